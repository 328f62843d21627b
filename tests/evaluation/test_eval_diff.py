"""`mimic eval-diff`: two eval runs side by side (known answers on small reports, then two real runs)."""

from __future__ import annotations

import json

import pytest

from services.cli import main as mimic_main
from services.evaluation.run_diff import RunDiffError, diff_runs, format_diff
from services.ingest.bvh import parse_bvh, write_bvh
from tests.support.goal_metrics import errors, hqp_meeting_every_goal, peer

CLIP = "dataset-1_bye_normal_001.bvh"
FRAMES = 45  # 1.5 s at 30 fps


def _report(clips: dict[str, dict[str, dict]], **settings) -> dict:
    return {"clips": [{"clip": c, "algos": a} for c, a in clips.items()], "settings": settings}


def _m(wrist: float, elbow: float, collisions: int = 0) -> dict:
    return {"wrist_err_cm": {"mean": wrist, "p99": 4 * wrist}, "elbow_err_cm": {"mean": elbow, "p99": None},
            "self_collisions": collisions}  # fmt: skip


def test_known_answers():
    """Deltas, the clips that moved past the threshold (and past the metric's floor), plain means over the shared
    clips, clips one run alone has, and the settings that differ (nested keys, the wall time left out)."""
    base = _report({"a": {"hqp": _m(0.10, 1.00), "wqp": _m(0.2, 1.0)}, "b": {"hqp": _m(0.004, 2.00)},
                    "gone": {"hqp": _m(1.0, 1.0)}},
                   solver={"cost": 0.0, "gain": 200}, wall_s=10.0)  # fmt: skip
    new = _report({"a": {"hqp": _m(0.12, 0.90, collisions=3)}, "b": {"hqp": _m(0.006, 2.04)}, "added": {"hqp": {}}},
                  solver={"cost": 0.3, "gain": 200}, wall_s=99.0)  # fmt: skip
    d = diff_runs(base, new, threshold=0.05)
    assert list(d["clips"]) == ["a", "b"] and d["only_base"] == ["gone"] and d["only_new"] == ["added"]
    assert list(d["clips"]["a"]) == ["hqp"]  # wqp: not run by both on every shared clip
    u, v, delta = d["clips"]["a"]["hqp"]["elbow_err_cm.mean"]
    assert (u, v) == (1.00, 0.90) and delta == pytest.approx(-0.10)
    assert d["clips"]["a"]["hqp"]["self_collisions"] == [0.0, 3.0, 3.0]
    assert d["clips"]["a"]["hqp"]["elbow_err_cm.p99"] == [None, None, None]
    moved = d["moved"]["hqp"]
    # a: elbow -10 % (better), wrist +20 % and +0.02 cm (worse); b: elbow +2 % (under the threshold), wrist +50 %
    # but only 0.002 cm (under the 0.01 cm floor)
    assert moved["elbow_err_cm.mean"] == {"better": ["a"], "worse": []}
    assert moved["wrist_err_cm.mean"] == {"better": [], "worse": ["a"]}
    assert d["means"]["hqp"]["elbow_err_cm.mean"] == pytest.approx([1.5, 1.47])
    assert d["settings"] == {"solver.cost": [0.0, 0.3]}
    assert diff_runs(base, new, algos=["hqp"])["clips"]["a"].keys() == {"hqp"}


@pytest.mark.parametrize(
    ("base", "new", "algos", "message"),
    [
        ({"summary": {}}, _report({"a": {"hqp": {}}}), None, "base: not a mimic eval report"),
        (_report({"a": {"hqp": {}}}), _report({"b": {"hqp": {}}}), None, "no clip in common"),
        (_report({"a": {"hqp": {}}}), _report({"a": {"hqp": {}}}), ["mink"], "algorithm(s) ['mink'] not run"),
    ],
)
def test_reports_that_cannot_be_compared_say_why(base, new, algos, message):
    with pytest.raises(RunDiffError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        diff_runs(base, new, algos)


@pytest.fixture(scope="module")
def two_runs(bvh_clips, tmp_path_factory):
    """The same real clip slice evaluated twice: shipped settings, and with the waist damped (cost 0.3)."""
    tmp = tmp_path_factory.mktemp("runs")
    data = parse_bvh(next(p for p in bvh_clips if p.name == CLIP))
    data.motion = data.motion[:FRAMES]
    clip = write_bvh(tmp / CLIP, data)
    out = []
    for name, flags in (("base", []), ("damped", ["--waist-damping-cost", "0.3"])):
        path = tmp / f"{name}.json"
        cmd = ["eval", str(clip), "--algos", "hqp-nullspace,wqp", "--no-sim", "--no-ik-check", "--json", str(path)]
        assert mimic_main([*cmd, *flags]) == 0
        out.append(path)
    return out


def test_two_real_runs_side_by_side(two_runs, tmp_path, capsys):
    """On two real runs the diff names the one setting that changed, carries each run's own figures, and shows the
    damping doing what it is for: the HQP's waist slower, the WQP (which has no such row) unchanged."""
    base_path, new_path = two_runs
    capsys.readouterr()
    out = tmp_path / "diff.json"
    assert mimic_main(["eval-diff", str(base_path), str(new_path), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "settings changed: solver.waist_damping_cost 0.0 -> 0.3" in text
    assert f"{CLIP[:-4]} " in text and "hqp-nullspace: means over clips, base -> new" in text
    d = json.loads(out.read_text())
    base, new = (json.loads(p.read_text())["clips"][0]["algos"] for p in two_runs)
    row = d["clips"][CLIP[:-4]]
    for algo in ("hqp-nullspace", "wqp"):
        assert row[algo]["elbow_err_cm.mean"][:2] == [
            base[algo]["elbow_err_cm"]["mean"],
            new[algo]["elbow_err_cm"]["mean"],
        ]
    hqp_waist = row["hqp-nullspace"]["waist_speed_rms"]
    assert hqp_waist[1] < 0.35 * hqp_waist[0], hqp_waist  # measured 1.54 -> 0.32 rad/s
    assert row["wqp"]["waist_speed_rms"][2] == 0.0


def test_unreadable_reports_are_one_line_errors(two_runs, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    for args, message in (
        ([str(two_runs[0]), str(bad)], f"{bad}: not JSON"),
        ([str(tmp_path / "missing.json"), str(two_runs[0])], "missing.json: cannot read"),
        ([*map(str, two_runs), "--threshold", "-1"], "--threshold -1.0 must be >= 0"),
    ):
        capsys.readouterr()
        assert mimic_main(["eval-diff", *args]) == 2
        out = capsys.readouterr()
        assert out.out == "" and len(out.err.strip().splitlines()) == 1 and message in out.err


def test_the_fidelity_goals_before_and_after():
    """The goals are recomputed from each run's metrics (reports written before the goals existed compare too): every
    goal met on 2 -> 1 of the shared clips, with the goal newly met and the ones newly missed named per clip."""
    base = _report(
        {
            "a": {"hqp-nullspace": hqp_meeting_every_goal(), "wqp": peer(0.08, 0.45)},
            "b": {"hqp-nullspace": hqp_meeting_every_goal(stuck_s=0.4), "wqp": peer(0.08, 0.45)},
            "c": {"hqp-nullspace": hqp_meeting_every_goal(), "wqp": peer(0.08, 0.45)},
        }
    )
    new = _report(
        {
            "a": {"hqp-nullspace": hqp_meeting_every_goal(stuck_s=0.2), "wqp": peer(0.08, 0.30)},
            "b": {"hqp-nullspace": hqp_meeting_every_goal(), "wqp": peer(0.08, 0.45)},
            "c": {"hqp-nullspace": hqp_meeting_every_goal(wrist_err_cm=errors(0.05, 1.1)), "wqp": peer(0.08, 0.45)},
        }
    )
    g = diff_runs(base, new)["goals"]
    assert g["clips"] == 3 and g["all_met"] == [2, 1]
    assert g["newly_met"] == {"stuck_s": ["b"]}
    assert g["newly_missed"] == {"stuck_s": ["a"], "wrist_p99_cm": ["c"], "elbow_behind_wqp_cm": ["a"]}
    assert g["newly_missed_causes"] == {}  # the new run wrote no goals: nothing to say why
    text = format_diff(diff_runs(base, new))
    assert "fidelity goals (hqp-nullspace): every goal met on 2 -> 1 of 3 shared clips" in text
    assert "  newly missed: stuck_s on a" in text
    # the new run's own goals blocks: a miss it explained at the default bar gets its main cause, one judged at
    # another bar (a --goals file) does not
    why = {"main": "acceleration", "shares": {"acceleration": 1.0}, "base": {"acceleration": 0.37}}
    new["clips"][2]["goals"] = {"checks": {"wrist_p99_cm": {"bar": 1.0, "met": False, "causes": why}}}
    new["clips"][0]["goals"] = {"checks": {"stuck_s": {"bar": 0.5, "met": False, "causes": why}}}
    g = diff_runs(base, new)["goals"]
    assert g["newly_missed_causes"] == {"wrist_p99_cm": {"c": {"cause": "acceleration", "share": 1.0, "base": 0.37}}}
    text = format_diff(diff_runs(base, new))
    assert "  newly missed: wrist_p99_cm on c [acceleration 100 % vs 37 %]" in text
    assert "  newly missed: stuck_s on a" in text
    assert diff_runs(_report({"a": {"wqp": {}}}), _report({"a": {"wqp": {}}}))["goals"] is None  # no HQP: none
