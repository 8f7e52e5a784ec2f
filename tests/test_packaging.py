"""The wheel ships what the command line names (issue 18): docs/ and samples/ as package data.

Building a wheel needs the build backend from the network, so the configuration is
checked here; ``pip wheel . --no-deps`` lists hbvs_cli/docs/*.md and
hbvs_cli/samples/{gains.toml,camera.yaml,pendant.csv} (checked by hand for issue 18).
"""

from __future__ import annotations

import fnmatch
import re
import sys

from conftest import REPO, run_hbvs

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def setuptools_config() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]


def shipped_files() -> set[str]:
    """Every non-Python file the wheel holds, as paths in the checkout (docs/x.md)."""
    config = setuptools_config()
    files = set()
    for package, patterns in config["package-data"].items():
        folder = REPO / config["package-dir"].get(package, package.replace(".", "/"))
        for path in folder.iterdir():
            if any(fnmatch.fnmatch(path.name, pattern) for pattern in patterns):
                files.add(str(path.relative_to(REPO)))
    return files


def test_every_subpackage_is_listed():
    listed = set(setuptools_config()["packages"])
    found = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "hbvs_cli").rglob("__init__.py")}
    assert found <= listed, f"add {sorted(found - listed)} to [tool.setuptools] packages in pyproject.toml"


def test_the_files_that_help_and_messages_name_are_shipped():
    named = set()
    for source in (REPO / "hbvs_cli").rglob("*.py"):
        # The docs/ and samples/ names that help texts and messages write out.
        named |= set(re.findall(r"((?:docs|samples)/[\w.-]+\.(?:md|toml))", source.read_text()))
    named |= {"docs/report.md"}  # the report's verdict table names it
    assert {"docs/method.md", "docs/report.md", "samples/gains.toml"} <= named
    assert named <= shipped_files()


def test_help_names_files_that_exist():
    """Help names shipped files by short names (docs/method.md) and says once where they are."""
    from pathlib import Path

    text = run_hbvs("--help", env={"COLUMNS": "400"}).stdout.decode()
    root = re.search(r"installed in (/\S+?)\.?\s*│?\n", text)
    assert root, text
    text += run_hbvs("repeat", "--help", env={"COLUMNS": "400"}).stdout.decode()
    names = set(re.findall(r"((?:docs|samples)/[\w.-]+\.(?:md|toml))", text))
    assert names == {"docs/method.md", "docs/report.md", "samples/gains.toml", "docs/robustness.md", "docs/robot.md"}
    assert all((Path(root.group(1)) / name).is_file() for name in names), (root.group(1), names)
    assert "site-packages" not in text and str(REPO) not in text.replace(root.group(1), "")
