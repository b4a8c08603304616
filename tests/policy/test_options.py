"""CCDP's own options stay few, and one quantity has one default: a recipe field named as a policy field
takes the policy's value."""

from dataclasses import MISSING, fields

from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

from lerobot_ccdp.datasets.recipe_file import RecoveryRecipe
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

# Issue 112: CCDPConfig had 32 options of its own, 8 of them set by nothing shipped.
MAX_OWN_FIELDS = 25


def _defaults(cls: type) -> dict:
    return {
        f.name: f.default if f.default is not MISSING else f.default_factory()
        for f in fields(cls)
        if f.default is not MISSING or f.default_factory is not MISSING
    }


def test_ccdp_adds_at_most_25_options_to_lerobots_diffusion_policy():
    """Own fields: those of CCDPConfig that LeRobot's DiffusionConfig (and so PreTrainedConfig) lacks; the
    diffusion, vision and optimizer fields keep LeRobot's meaning."""
    lerobot = {f.name for f in fields(DiffusionConfig)}
    own = [f.name for f in fields(CCDPConfig) if f.name not in lerobot]
    assert len(own) <= MAX_OWN_FIELDS, own


def test_a_recipe_field_named_as_a_policy_field_reads_the_policys_value():
    """`recovery:`'s fields that share a name with CCDPConfig's default to None, which synthesis replaces with
    the base checkpoint's value (`RecoveryRecipe.for_checkpoint`), or to the policy's own default. Before,
    `delta_z` was 0.5 in a recipe and 0.1 in the policy."""
    recipe, policy = _defaults(RecoveryRecipe), _defaults(CCDPConfig)
    shared = sorted(set(recipe) & set(policy))
    assert shared, "RecoveryRecipe and CCDPConfig share no field: nothing to check"
    for name in shared:
        assert recipe[name] is None or recipe[name] == policy[name], (name, recipe[name], policy[name])
    checkpoint = CCDPConfig(delta_z=0.3, device="cpu")
    assert RecoveryRecipe.from_dict({}).for_checkpoint(checkpoint, "recipe").delta_z == 0.3
    assert RecoveryRecipe.from_dict({"delta_z": 0.5}).for_checkpoint(checkpoint, "recipe").delta_z == 0.5
