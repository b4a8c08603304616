"""`lerobot_ccdp.benchmark.preference_family --report-only` tabulates members whose results.json was carried
between machines without its planned chunks ("positions", most of the file): the tables need only the shares,
and the panel grid draws the members that kept their chunks; the header describes what the members were
measured with."""

import json
from pathlib import Path

import numpy as np
import pytest

from lerobot_ccdp.benchmark import preference_family as bench
from lerobot_ccdp.benchmark.task_settings import defaults
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

NAMES = ("DP", "CCDP set denoiser")
# What `measured_settings` kept for members measured before the Fourier octaves were recorded.
SETTINGS = {
    "rows": 2048,
    "base_steps": 1000,
    "head_steps": 12000,
    "episodes": 100,
    "classifier": False,
    "set_denoiser": True,
    "set_states": 2048,
}


def member(seed: int, positions: bool) -> dict:
    """A member's results as `measure` writes them, with made-up shares and, with `positions`, chunks heading
    out from the origin."""
    scores = {"failed": [0], "failed_share": 0.01, "failed_on_path_share": 0.0, "preference_error": 0.04}
    result = {
        "goals": 3,
        "labelled": seed % 2 == 0,
        "methods": {name: {count: dict(scores) for count in "12"} for name in NAMES},
        "positions": {},
    }
    if positions:
        chunks = np.cumsum(np.full((4, 8, 2), 0.05), axis=1).tolist()
        result["positions"] = {f"{name}|{count}": chunks for name in NAMES for count in "12"}
    return result


def test_the_grid_draws_the_members_that_kept_their_chunks(tmp_path: Path) -> None:
    results = {100: member(100, positions=True), 101: member(101, positions=False)}
    assert "| 101 |" in bench.table(results)  # the shares alone make the table
    bench.panel_grid(results, tmp_path / "grid.png", "CCDP set denoiser")
    assert (tmp_path / "grid.png").stat().st_size > 0


def test_no_grid_when_no_member_kept_its_chunks(tmp_path: Path) -> None:
    (tmp_path / "grid.png").write_bytes(b"an earlier report's grid")
    bench.panel_grid({101: member(101, positions=False)}, tmp_path / "grid.png", "CCDP set denoiser")
    assert not (tmp_path / "grid.png").exists()


def test_the_header_describes_what_the_members_were_measured_with_not_the_report_commands_defaults() -> None:
    measured = {seed: {**member(seed, positions=False), "settings": SETTINGS} for seed in (100, 101)}
    line = bench.settings_line(measured)
    assert line.startswith("2048 chunks each") and "heads 12000 steps" in line and "on 2048 states" in line
    carried = {**measured, 102: member(102, positions=False)}  # measured before settings were kept
    line = bench.settings_line(carried)
    assert "members [100, 101]: 2048 chunks each" in line and "members [102]: settings not recorded" in line


def test_the_header_names_the_label_free_heads_fourier_octaves_where_they_had_some() -> None:
    measured = {
        100: {**member(100, positions=False), "settings": {**SETTINGS, "z_fourier_octaves": 0}},
        101: {**member(101, positions=False), "settings": {**SETTINGS, "z_fourier_octaves": 4}},
    }
    line = bench.settings_line(measured)
    assert "members [101]: " in line and "a final_state z in 4 Fourier octaves" in line
    assert "members [100]: " in line and line.count("Fourier") == 1


def test_the_header_names_the_heads_trained_with_stratum_weights() -> None:
    measured = {
        100: {**member(100, positions=False), "settings": SETTINGS},
        101: {**member(101, positions=False), "settings": {**SETTINGS, "stratum_weights": True}},
    }
    line = bench.settings_line(measured)
    assert "members [101]: " in line and line.count("rows weighed per (state, failure set)") == 1


def test_against_a_variant_the_differences_are_paired_member_by_member() -> None:
    """The reported members' preference error below the variant's by 0.02 (member 100) and 0.04 (101): the
    difference is -0.03 with an interval over the two, and member 102, reported only, is left out."""
    longer = {seed: member(seed, positions=False) for seed in (100, 101, 102)}
    shorter = {seed: member(seed, positions=False) for seed in (100, 101)}
    for seed, lower in ((100, 0.02), (101, 0.04)):
        for count in "12":
            longer[seed]["methods"]["CCDP set denoiser"][count]["preference_error"] = 0.04 - lower
    text = bench.variant_difference(longer, shorter)
    assert "paired over members [100, 101]" in text
    rows = {
        line.split(" | ")[0] + line.split(" | ")[1]: line
        for line in text.splitlines()
        if line.startswith("| ")
    }
    assert rows["| CCDP set denoiser1"].endswith("| 0.000 [0.000, 0.000] | -0.030 [-0.040, -0.020] |")
    assert rows["| DP1"].endswith("| 0.000 [0.000, 0.000] | 0.000 [0.000, 0.000] |")


def test_against_a_variant_with_none_of_the_members_is_refused() -> None:
    with pytest.raises(ValueError, match="none of the reported members"):
        bench.variant_difference({100: member(100, False)}, {101: member(101, False)})


def test_each_guard_setting_adds_the_set_denoisers_forms_with_the_guard_on_that_many_last_steps() -> None:
    sampling = bench.argparse.Namespace(
        w_z=[1.0, 2.0], w_z_steps=[3], guard_steps=[0, 4], guard_weight=[1.0], baselines=False
    )
    forms = bench.methods("set_denoiser", True, sampling, demos=None)
    assert forms["CCDP set denoiser guard last 4"].fields["failure_guard_steps"] == 4
    assert forms["CCDP set denoiser w_z=2 first 3 steps"].fields["failure_guard_steps"] == 0
    assert forms["CCDP set denoiser w_z=2 first 3 steps guard last 4"].fields["w_z_steps"] == 3
    assert len(forms) == 5  # DP* at CCDP's cost and the four forms


def test_each_guard_weight_adds_the_guarded_forms_at_that_weight_and_leaves_the_unguarded_alone() -> None:
    sampling = bench.argparse.Namespace(
        w_z=[1.0], w_z_steps=[0], guard_steps=[0, 4], guard_weight=[1.0, 8.0], baselines=False
    )
    forms = bench.methods("set_denoiser", True, sampling, demos=None)
    assert forms["CCDP set denoiser guard last 4 w_g=8"].fields["failure_guard_weight"] == 8.0
    assert forms["CCDP set denoiser guard last 4"].fields["failure_guard_weight"] == 1.0
    assert "failure_guard_weight" not in forms["CCDP set denoiser"].fields
    assert len(forms) == 4  # DP* at CCDP's cost, the unguarded form and the guarded one at each weight


def test_report_only_merges_members_run_side_by_side_into_one_report(tmp_path: Path, capsys) -> None:
    """`--report-only --merge`: members measured under their own --out folders are tabulated together into
    --out (its results.json, preferences.md and panel grid), and nothing is trained or measured."""
    for seed in (100, 101):
        (tmp_path / f"member{seed}").mkdir()
        results = {seed: {**member(seed, positions=seed == 100), "settings": SETTINGS}}
        (tmp_path / f"member{seed}" / "results.json").write_text(json.dumps(results))
    out = tmp_path / "family"
    bench.main(
        ["--report-only", "--members", "100", "101", "102", "--out", str(out)]
        + ["--merge", str(tmp_path / "member100"), str(tmp_path / "member101")]
    )
    printed = capsys.readouterr().out
    assert "| 100 |" in printed and "| 101 |" in printed and "| 102 |" not in printed  # 102: never measured
    assert "Over the 2 members" in printed
    assert sorted(json.loads((out / "results.json").read_text())) == ["100", "101"]
    assert (
        (out / "preferences.md").read_text().startswith("Failed share / preference error; members [100, 101]")
    )
    assert (out / "preferences.png").stat().st_size > 0  # member 100 kept its chunks


def test_the_family_measures_the_policy_s_defaults_unless_told_otherwise():
    """Issue 114, item 7: the family's set denoiser is measured at CCDPConfig's sampling settings, the one
    configuration of the Panda tasks, so a change of the policy's defaults moves the family with it."""
    policy = defaults(CCDPConfig)
    forms = bench.methods("set_denoiser", False, bench.build_parser().parse_args([]), None)
    ccdp = [m for m in forms.values() if m.mode == "ccdp"]
    assert len(ccdp) == 1
    assert ccdp[0].fields == {
        "w_z": policy["w_z"],
        "w_z_steps": policy["w_z_steps"],
        "failure_guard_steps": policy["failure_guard_steps"],
        "failure_guard_weight": policy["failure_guard_weight"],
    }
    earlier = bench.build_parser().parse_args(["--w-z", "1", "--guard-weight", "1"])
    (form,) = [m for m in bench.methods("set_denoiser", False, earlier, None).values() if m.mode == "ccdp"]
    guard = policy["failure_guard_steps"]
    assert form.fields == {
        "w_z": 1.0,
        "w_z_steps": None,
        "failure_guard_steps": guard,
        "failure_guard_weight": 1.0,
    }
