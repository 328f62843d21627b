"""The fidelity goals of an eval run (``services/evaluation/goals.py``): known answers on hand-made metric blocks."""

from __future__ import annotations

import pytest

from services.evaluation.goals import GOAL_KEYS, clip_goals, goals_lines, goals_summary, load_bars
from tests.support.goal_metrics import errors, hqp_meeting_every_goal, peer


def test_a_clip_meeting_every_goal():
    g = clip_goals({"hqp-nullspace": hqp_meeting_every_goal(), "wqp": peer(0.08, 0.45), "mink": peer(0.13, 0.38)})
    assert g["all_met"] and g["unmet"] == [] and g["not_judged"] == []
    assert set(g["checks"]) == set(GOAL_KEYS)
    assert g["checks"]["elbow_behind_mink_cm"]["value"] == pytest.approx(0.02)  # 0.40 - 0.38: within the tie
    assert g["checks"]["wrist_behind_mink_cm"]["value"] == pytest.approx(-0.08)


def test_each_missed_goal_is_named_and_nothing_else():
    algos = {
        "hqp-nullspace": hqp_meeting_every_goal(wrist_err_cm=errors(0.05, 1.2), stuck_s=0.15, min_clearance_cm=0.8),
        "wqp": peer(0.08, 0.30),  # the HQP's elbow 0.10 cm behind: past the 0.05 tie
        "mink": peer(0.05, 0.50),  # the same wrist mean as the HQP's: not below it
    }
    g = clip_goals(algos)
    assert g["unmet"] == ["wrist_p99_cm", "stuck_s", "min_clearance_cm", "elbow_behind_wqp_cm", "wrist_behind_mink_cm"]
    assert not g["all_met"]
    assert g["checks"]["wrist_p99_cm"] == {"value": 1.2, "bar": 1.0, "op": "<=", "met": False}


def test_goals_without_their_figures_are_not_judged():
    """No peers in the run, and a marker clip whose targets carry no orientation: those goals are listed as not
    judged, and the clip meets the others."""
    no_rotation = {"mean": None, "p99": None, "max": None}
    g = clip_goals({"hqp-nullspace": hqp_meeting_every_goal(wrist_rot_err_deg=no_rotation)})
    assert g["not_judged"] == [
        "wrist_rotation_p99_deg",
        "elbow_behind_wqp_cm",
        "elbow_behind_mink_cm",
        "wrist_behind_mink_cm",
    ]
    assert g["all_met"]
    assert clip_goals({"wqp": peer(0.1, 0.2)}) is None  # the HQP did not run: nothing to judge


def test_bars_from_a_file(tmp_path):
    f = tmp_path / "bars.toml"
    f.write_text("[bars]\nwrist_p99_cm = 1.5\nelbow_mean_cm = 0.3\n")
    bars = load_bars(f)
    assert bars == {"wrist_p99_cm": 1.5, "elbow_mean_cm": 0.3}
    g = clip_goals({"hqp-nullspace": hqp_meeting_every_goal(wrist_err_cm=errors(0.05, 1.2))}, bars)
    assert g["unmet"] == ["elbow_mean_cm"]  # 1.2 cm is within the wider wrist bar; 0.4 past the tighter elbow one
    assert g["checks"]["elbow_mean_cm"]["bar"] == 0.3


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("[bars]\nwrist_p99 = 1.5\n", "unknown goals ['wrist_p99']"),
        ("[bars]\nwrist_p99_cm = 'one'\n", "bars must be numbers"),
        ("wrist_p99_cm = 1.5\n", "needs a [bars] table"),
        ("[bars\n", "goals file"),
    ],
)
def test_a_bad_bars_file_is_one_line(tmp_path, text, says):
    f = tmp_path / "bars.toml"
    f.write_text(text)
    with pytest.raises(ValueError, match=r"goals file") as err:
        load_bars(f)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_summary_counts_clips_per_goal():
    per = {
        "a": clip_goals({"hqp-nullspace": hqp_meeting_every_goal(), "mink": peer(0.13, 0.38)}),
        "b": clip_goals({"hqp-nullspace": hqp_meeting_every_goal(stuck_s=0.3), "mink": peer(0.13, 0.20)}),
        "c": clip_goals({"hqp-nullspace": hqp_meeting_every_goal()}),
        "d": None,  # the HQP did not run on it
    }
    s = goals_summary(per)
    assert (s["clips"], s["all_met"]) == (3, 2)
    assert s["goals"]["stuck_s"] == {"judged": 3, "met": 2, "unmet_clips": ["b"]}
    assert s["goals"]["elbow_behind_mink_cm"] == {"judged": 2, "met": 1, "unmet_clips": ["b"]}
    assert "elbow_behind_wqp_cm" not in s["goals"]  # judged on no clip
    lines = goals_lines(s)
    assert lines[0] == "fidelity goals (hqp-nullspace): 2 of 3 clips meet every one"
    assert [ln.split(":")[0].strip() for ln in lines[1:]] == ["stuck_s", "elbow_behind_mink_cm"]
