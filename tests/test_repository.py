"""The repository itself: the README's commands, CI, samples, the CLI's surface."""

from __future__ import annotations

import re

import numpy as np
import subprocess
import sys

from conftest import REPO, SAMPLES, call_hbvs, run_hbvs


def readme_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    return re.findall(r"```bash\n(python3 -m venv[^\n]*)\n```", text)


def test_ci_runs_exactly_the_readme_test_command():
    demo, tests = readme_commands()[:2]
    assert "hbvs demo" in demo and "pytest" in tests
    ci = (REPO / ".ci" / "run").read_text().strip().splitlines()
    assert ci.count(tests) == 1
    # After it, only the real-ROS-2 run and the live campaign (their own markers, not part of the README's suite).
    assert ci[ci.index(tests) + 1:] == ["python -m pytest -q -n 0 -m ros2_real tests/test_ros2_real.py",
                                        "python -m pytest -q -n 0 -m campaign tests/test_live_faults.py tests/test_live_base.py tests/test_live_loop.py "
                                        "tests/test_route_live.py"]


def test_every_sample_is_small_and_used_by_a_test():
    used = "\n".join(p.read_text() for p in (REPO / "tests").glob("test_*.py"))
    for sample in SAMPLES.iterdir():
        if sample.suffix in (".sh", ".md"):
            continue
        assert sample.stat().st_size < 2 * 2**20, sample
        assert sample.name in used, f"samples/{sample.name} is used by no test"


def test_help_and_version():
    result = run_hbvs("--help")
    assert result.returncode == 0
    for command in ("teach", "fit", "repeat", "report", "demo"):
        assert command in result.stdout.decode()
    version = run_hbvs("--version")
    assert version.returncode == 0 and version.stdout.decode().startswith("hbvs 0.")
    for command in ("teach", "fit", "repeat", "report", "demo"):
        assert call_hbvs(command, "--help").returncode == 0


def test_help_does_not_import_heavy_libraries():
    code = (
        "import sys; from hbvs_cli.cli.app import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "heavy = [m for m in ('cv2', 'scipy', 'matplotlib', 'mcap') if m in sys.modules]\n"
        "print('heavy:' + ','.join(heavy))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.stdout.strip().splitlines()[-1] == "heavy:"


def test_unexpected_errors_are_one_line_without_traceback(tmp_path):
    """A usage error and an input error: one line each, the right exit codes."""
    bad = run_hbvs("repeat", str(tmp_path / "none.mcap"), "--sim")
    assert bad.returncode == 3 and bad.stderr.decode().count("\n") == 1
    assert b"Traceback" not in bad.stderr


def test_the_sample_pendant_csv_is_the_default_s_curve():
    import numpy as np

    from hbvs_cli.core.path import PRESETS, sampled_profile
    from hbvs_cli.io.path_csv import load_command_profile

    profile = load_command_profile(SAMPLES / "pendant.csv")
    preset = PRESETS["s-curve"]
    expected = sampled_profile(preset.commands, preset.duration, 10.0)
    assert profile.t.size == 200 and profile.duration == 20.0
    assert np.allclose(profile.v, expected.v, atol=1e-6) and np.allclose(profile.w, expected.w, atol=1e-6)


def test_the_sample_fit_repeats_and_converges(tmp_path):
    from hbvs_cli.io.fit_file import read_fit_file
    from hbvs_cli.io.run_file import read_run

    from conftest import make_run

    model = read_fit_file(SAMPLES / "fit.mcap").model
    assert model.camera.width == 320 and model.frames.used == 200
    make_run(SAMPLES / "fit.mcap", tmp_path / "run.mcap", sim=True, perception="points", rate=30.0)
    run = read_run(tmp_path / "run.mcap")
    final = np.hypot(*(run.true_pose[-1, :2] - run.desired_pose[-1, :2]))
    assert final < 0.01


def test_help_shows_its_brackets():
    """The help is rich markup (rich_markup_mode="rich"), where [word] is a style tag that
    disappears: every bracket of a help text is escaped, so that the help shows what the
    text says (SeedSequence([seed, i]), pip install 'hbvs[sweep-cluster]')."""
    import re

    import typer.main
    from rich.text import Text

    from hbvs_cli.cli.app import app

    group = typer.main.get_command(app)
    checked = 0
    for command in group.commands.values():
        for parameter in command.params:
            help_text = getattr(parameter, "help", None) or ""
            shown = Text.from_markup(help_text).plain
            for bracketed in re.findall(r"\[[^\]]*\]", help_text.replace("\\[", "[")):
                assert bracketed in shown, (command.name, parameter.name, help_text)
                checked += 1
    assert checked >= 2
