"""Flags built from config dataclasses: defaults, help and validation come from the dataclass."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

from services.logger.cli import add_arguments as log_arguments
from services.logger.cli import configs as log_configs
from services.logger.config import LoggerConfig, RecordingConfig
from services.retarget.cli import add_retarget_options
from services.retarget.cli import config_from_args as retarget_config
from services.retarget.retargeter import RetargetConfig
from services.sim.cli import add_arguments as sim_arguments
from services.sim.cli import sim_config
from services.sim.sim_core import SimConfig
from services.solver.cli import add_arguments as solver_arguments
from services.solver.core import SolverConfig
from services.solver.node import config_from_args as solver_config
from shared.bus import add_bus_args
from shared.config import add_dataclass_arguments, attribute_docs, config_from_args


@dataclass
class Demo:
    """A config.

    Attributes:
        rate: control rate [Hz]; more text. level: 1 or 2.
        on: switch it on.
        off: a default-on switch.
    """

    rate: float = 500.0
    level: int = 1
    on: bool = False
    off: bool = True

    def __post_init__(self) -> None:
        if self.level not in (1, 2):
            raise ValueError(f"level must be 1 or 2, got {self.level}")


def _parser(add) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    add(p)
    return p


def test_flags_come_from_the_fields():
    assert attribute_docs(Demo) == {
        "rate": "control rate [Hz]; more text",
        "level": "1 or 2",
        "on": "switch it on",
        "off": "a default-on switch",
    }
    p = _parser(lambda p: add_dataclass_arguments(p, Demo))
    assert config_from_args(Demo, p.parse_args([])) == Demo()
    got = config_from_args(Demo, p.parse_args(["--rate", "250", "--level", "2", "--on", "--no-off"]))
    assert got == Demo(250.0, 2, True, False)
    assert "control rate [Hz]; more text (default: 500.0)" in " ".join(p.format_help().split())
    with pytest.raises(ValueError, match="level must be 1 or 2, got 3"):
        config_from_args(Demo, p.parse_args(["--level", "3"]))


def test_service_defaults_are_the_dataclass_defaults():
    # One source: no flags given == the dataclass defaults.
    assert sim_config(_parser(sim_arguments).parse_args([])) == SimConfig()
    assert solver_config(_parser(solver_arguments).parse_args([])) == SolverConfig()
    assert retarget_config(_parser(lambda p: (add_retarget_options(p), add_bus_args(p))).parse_args([])) == (
        RetargetConfig()
    )
    assert log_configs(_parser(log_arguments).parse_args([])) == (RecordingConfig(), LoggerConfig())


def test_renamed_and_new_flags():
    args = _parser(solver_arguments).parse_args(["--id", "b", "--gain", "100", "--rate", "250"])
    cfg = solver_config(args)
    assert (cfg.solver_id, cfg.gain, cfg.rate) == ("b", 100.0, 250.0)
    p = _parser(lambda p: (add_retarget_options(p), add_bus_args(p)))
    args = p.parse_args(["--mapping", "incremental", "--incremental-scale", "0.5", "--mode", "client"])
    cfg = retarget_config(args)
    assert (cfg.mode, cfg.incremental_scale, args.mode) == ("incremental", 0.5, "client")  # no clash with --mode
    with pytest.raises(SystemExit):
        p.parse_args(["--gain", "0.5"])  # the misleading name is gone
    args = _parser(sim_arguments).parse_args(["--watchdog", "0.2", "--follow", "b", "--no-velocity-ff"])
    cfg = sim_config(args)
    assert (cfg.watchdog, cfg.solver_id, cfg.velocity_feedforward) == (0.2, "b", False)
    args = _parser(log_arguments).parse_args(["--no-meshes", "--no-compact", "--operator-offset", "0,-1,0.5"])
    rc, lc = log_configs(args)
    assert (lc.meshes, rc.compact, lc.operator_offset) == (False, False, (0.0, -1.0, 0.5))


@pytest.mark.parametrize(
    ("cls", "kw", "match"),
    [
        (SolverConfig, {"algo": "nope"}, r"known: \['clik-mimicry', 'clik-nullspace'"),
        (SolverConfig, {"qp": "nope"}, r"known: \['daqp', 'piqp'\]"),
        (SolverConfig, {"gain": 0.0}, "gains"),
        (SimConfig, {"watchdog": 0.0}, "watchdog must be > 0"),
        (RetargetConfig, {"incremental_scale": -1.0}, "incremental_scale"),
        (LoggerConfig, {"queue": 0}, "queue must be >= 1"),
        (LoggerConfig, {"robot_rate": float("nan")}, "must be finite"),
        (RecordingConfig, {"grpc_port": 70000}, "grpc_port must be a TCP port"),
    ],
)
def test_configs_validate_themselves(cls, kw, match):
    with pytest.raises(ValueError, match=match):
        cls(**kw)
