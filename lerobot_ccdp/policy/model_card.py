"""The model card of a pushed ccdp checkpoint.

LeRobot's own template only knows its built-in policies ("Model type not recognized"); a reader of a ccdp
checkpoint needs to know which package provides the policy type and how the two stages and evaluation run.
"""

from importlib.resources import files

from huggingface_hub import ModelCard, ModelCardData

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

TEMPLATE = "ccdp_modelcard_template.md"


def make_model_card(
    config: CCDPConfig,
    dataset_repo_id: str,
    license: str | None,
    tags: list[str] | None,
    recovery_trained: bool,
) -> ModelCard:
    """Same metadata as LeRobot's card (so the Hub lists it as a LeRobot robotics model), ccdp's own text."""
    card_data = ModelCardData(
        license=license or "apache-2.0",
        library_name="lerobot",
        pipeline_tag="robotics",
        tags=sorted(set(tags or []) | {"robotics", "lerobot", "ccdp", "failure-recovery"}),
        model_name="ccdp",
        datasets=dataset_repo_id,
    )
    template = files("lerobot_ccdp").joinpath("templates", TEMPLATE).read_text(encoding="utf-8")
    card = ModelCard.from_template(
        card_data,
        template_str=template,
        repo_id=config.repo_id or "<repo_id>",
        training_stage=config.training_stage,
        recovery_trained=recovery_trained,
        failure_feature=config.failure_feature,
    )
    card.validate()  # as LeRobot's card: the Hub refuses metadata it cannot parse
    return card
