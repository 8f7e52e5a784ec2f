"""The options are declared once, as the fields of each stage's options dataclass (hbvs_cli/settings):
the command line, the config keys, the sweep's parameters and the help all come from them, and
their values are checked once, where the options are made."""

from __future__ import annotations

import dataclasses
import math

import pytest
import typer

from hbvs_cli.cli.app import app
from hbvs_cli.core.controller import ControllerGains
from hbvs_cli.settings.config import SCHEMA, TABLES, load_config
from hbvs_cli.stages import repeat as repeat_stage
from hbvs_cli.stages.repeat import resolve_settings
from hbvs_cli.settings.commands import (
    DEFAULT_LOST_TIMEOUT, DEFAULT_MAX_V, DEFAULT_MAX_W, DEFAULT_OFFSET, REPEAT, REPEAT_SETTINGS, SIMULATION_DEFAULTS,
    TEACH_SETTINGS, RepeatOptions,
)
from hbvs_cli.stages.teach import TeachOptions

from conftest import REPO

#: A config file that sets every option the two precedence bugs were about.
CONFIG = """
[run]
offset = "0.3,-0.2,5"
pixel_noise = 0.7
lost_timeout = 9.0
perception = "points"
"""


def parsed_options(monkeypatch, *args: str) -> RepeatOptions:
    """The RepeatOptions the command line hands to the stage (the stage itself not run)."""
    seen = []
    monkeypatch.setattr(repeat_stage, "run_repeat", lambda options, console: seen.append(options))
    app(args=["repeat", "fit.mcap", "--sim", "-q", *args], prog_name="hbvs", standalone_mode=False)
    return seen[0]


def resolved(options: RepeatOptions):
    return resolve_settings(options, dhat0_suggested=4.0, taught_rate=30.0)


@pytest.fixture
def config_file(tmp_path):
    path = tmp_path / "config.toml"
    path.write_text(CONFIG)
    return path


def test_an_explicit_offset_equal_to_the_default_beats_the_config(monkeypatch, config_file):
    options = parsed_options(monkeypatch, "--config", str(config_file), "--offset", DEFAULT_OFFSET)
    assert options.offset == DEFAULT_OFFSET
    dx, dy, dtheta = resolved(options).offset
    assert (dx, dy, math.degrees(dtheta)) == pytest.approx((-0.1, 0.05, 2.0), abs=1e-12)
    # Not given: the config's (it lost to the default text before only when given).
    dx, dy, dtheta = resolved(parsed_options(monkeypatch, "--config", str(config_file))).offset
    assert (dx, dy, math.degrees(dtheta)) == pytest.approx((0.3, -0.2, 5.0), abs=1e-12)


def test_pixel_noise_zero_beats_the_config(monkeypatch, config_file):
    options = parsed_options(monkeypatch, "--config", str(config_file), "--pixel-noise", "0")
    assert options.pixel_noise == 0.0
    assert resolved(options).pixel_noise == 0.0
    assert resolved(parsed_options(monkeypatch, "--config", str(config_file))).pixel_noise == 0.7


def test_every_option_equal_to_its_default_beats_the_config(monkeypatch, config_file):
    """The same bug class for the other options the config may set: given, they win."""
    settings = resolved(parsed_options(
        monkeypatch, "--config", str(config_file), "--lost-timeout", "3", "--perception", "images",
    ))
    assert settings.lost_timeout == DEFAULT_LOST_TIMEOUT and settings.perception == "images"
    settings = resolved(parsed_options(monkeypatch, "--config", str(config_file)))
    assert settings.lost_timeout == 9.0 and settings.perception == "points"


def test_without_options_or_config_the_defaults_hold(monkeypatch):
    settings = resolved(parsed_options(monkeypatch))
    gains = ControllerGains()
    assert (settings.gains.k_v, settings.gains.k_w, settings.gains.gamma, settings.gains.k_2) == (gains.k_v, gains.k_w, gains.gamma, gains.k_2)
    assert settings.limits.max_v == DEFAULT_MAX_V and settings.limits.max_w == DEFAULT_MAX_W and settings.limits.max_accel is None
    assert settings.lost_timeout == DEFAULT_LOST_TIMEOUT and settings.perception == "images" and settings.pixel_noise == 0.0
    assert settings.rate == 30.0 and settings.dhat0 == 4.0 and settings.speed == 1.0 and settings.latency == 0


def test_the_options_dataclass_and_the_command_line_have_the_same_fields():
    command = typer.main.get_command(app).commands["repeat"]
    cli_names = {param.name for param in command.params} - {"quiet"}
    assert cli_names == {f.name for f in dataclasses.fields(RepeatOptions)} == set(REPEAT)


def test_help_shows_the_defaults_of_the_one_table():
    command = typer.main.get_command(app).commands["repeat"]
    helps = {param.name: param.help for param in command.params}
    assert f"Default {DEFAULT_OFFSET}." in helps["offset"]
    assert f"Default {DEFAULT_MAX_V:g}." in helps["max_v"] and f"Default {ControllerGains().k_v:g}." in helps["k_v"]
    for setting in REPEAT_SETTINGS:
        if setting.config is not None:
            assert helps[setting.name].endswith(f"Default {setting.shown_default}."), setting.name


def test_every_config_key_is_one_option_of_the_same_type():
    keys = {key: kind for table in SCHEMA.values() for key, kind in table.items()}
    by_key = {setting.config: setting for setting in REPEAT_SETTINGS if setting.config is not None}
    assert set(by_key) == set(keys)
    for key, setting in by_key.items():
        assert setting.type is keys[key], key


def test_the_sample_gains_file_holds_the_code_defaults():
    """samples/gains.toml once drifted from the code (gamma 2000 and k_2 300 in one place,
    2500 and 400 in another): it must say what the code does."""
    sample = load_config(REPO / "samples" / "gains.toml")
    gains = ControllerGains()
    defaults = {"k_v": gains.k_v, "k_w": gains.k_w, "gamma": gains.gamma, "k_2": gains.k_2}
    for key, value in sample.items():
        setting = next(s for s in REPEAT_SETTINGS if s.config == key)
        expected = defaults[key] if key in defaults else setting.fallback
        assert value == expected, key
    assert {"k_v", "k_w", "gamma", "k_2", "law", "max_v", "max_w", "lost_timeout"} <= set(sample)


def test_teach_options_come_from_their_table_too():
    command = typer.main.get_command(app).commands["teach"]
    helps = {param.name: param.help for param in command.params}
    assert set(helps) - {"quiet"} == {f.name for f in dataclasses.fields(TeachOptions)} == {s.name for s in TEACH_SETTINGS}
    # The simulation's defaults are the table's, and --help shows them.
    assert SIMULATION_DEFAULTS == {"path": "s-curve", "route": None, "offset": None, "target": "dots", "dots": 3, "texture": None,
                                   "seed": 0, "noise": 2.0, "blur": 0.0, "noise_grain": 0.0, "exposure": 1.0,
                                   "video_out": None, "calibration_out": None}
    assert TeachOptions().for_simulation().noise == SIMULATION_DEFAULTS["noise"]
    assert helps["noise"].endswith("Default 2.") and helps["path"].endswith("Default s-curve.") and helps["dots"].endswith("Default 3.")


def test_the_options_are_declared_fields_a_type_checker_sees():
    import typing
    from pathlib import Path

    hints = typing.get_type_hints(RepeatOptions)
    assert hints["input"] is str and hints["dhat0"] == float | None and hints["occlude"] == list[str]
    assert hints["config"] == Path | None and hints["seed"] is int
    assert [s.name for s in REPEAT_SETTINGS] == [f.name for f in dataclasses.fields(RepeatOptions)]


@pytest.mark.parametrize("name, value", [("law", "pid"), ("perception", "pixels"), ("state_filter", "kalman")])
def test_a_choice_is_checked_once_at_each_boundary(tmp_path, name, value):
    """Made from the command line or by a stage, read from --config, or planned by a sweep: the same declaration refuses it."""
    from hbvs_cli.errors import UsageError
    from hbvs_cli.sweep.spec import build_spec

    allowed = REPEAT[name].allowed()
    message = f"{REPEAT[name].option_names[-1]} must be one of {', '.join(allowed)}, got {value!r}"
    with pytest.raises(UsageError) as made:
        RepeatOptions(input="fit.mcap", **{name: value})
    assert str(made.value) == message
    config = tmp_path / "bad.toml"
    key = REPEAT[name].config
    table = next(table for table, keys in TABLES.items() if key in keys)
    config.write_text((f"[{table}]\n" if table else "") + f'{key} = "{value}"\n')
    with pytest.raises(UsageError) as read:
        load_config(config)
    assert str(read.value) == f"{config}: {message}"
    if name != "state_filter":  # not a sweep parameter
        with pytest.raises(UsageError, match=f"{name} must be one of {', '.join(allowed)}"):
            build_spec(None, [], [f"{name}={value}"])


def test_the_sweep_parameters_take_their_kind_choices_and_bounds_from_the_options():
    from hbvs_cli.sweep.parameters import PARAMETERS

    assert (PARAMETERS["latency"].kind, PARAMETERS["rate"].kind, PARAMETERS["law"].kind) == ("int", "float", "choice")
    assert PARAMETERS["law"].choices == REPEAT["law"].allowed() == ("lateral-gain", "paper", "non-adaptive", "kanayama")
    assert PARAMETERS["perception"].choices == REPEAT["perception"].allowed() == ("points", "images")
    assert PARAMETERS["dhat0"].bound_violation(0.0) == REPEAT["dhat0"].violation(0.0) is not None
