"""The layers are a promise, read from the source with :mod:`ast`.

- core imports nothing of hbvs outside core (``errors`` aside);
- io imports neither perception, sim, report, sweep, stages nor cli;
- no stage imports another stage (``demo``, which runs them, aside);
- every topic and schema name is spelled once, in ``io/topics.py``.

Imports inside functions count the same as those at the top of a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import REPO

PACKAGE = REPO / "hbvs_cli"
#: Subpackages io must never reach.
ABOVE_IO = ("perception", "sim", "report", "sweep", "stages", "cli", "tools")
#: Modules of ``stages`` that are shared helpers, not subcommands: any stage may use them.
STAGE_HELPERS = ("console", "options", "settings", "frames", "live")  # live: the loop of repeat --live


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path) -> set[str]:
    """Every hbvs_cli module that ``path`` imports (absolute names), wherever the import is."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("hbvs_cli"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("hbvs_cli"):
                continue
            found.add(target)
            # `from . import x` names a module, not an attribute.
            found.update(f"{target}.{alias.name}" for alias in node.names if _is_module(f"{target}.{alias.name}"))
    return found


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").exists() or (path / "__init__.py").exists()


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


SOURCES = sorted(PACKAGE.rglob("*.py"))


def violations() -> list[str]:
    found = []
    for path in SOURCES:
        name = module_name(path)
        own = layer(name)
        for target in sorted(imported_modules(path)):
            other = layer(target)
            if own == "core" and other not in ("core", "errors"):
                found.append(f"{name} -> {target} (core imports only core and errors)")
            elif own == "io" and other in ABOVE_IO:
                found.append(f"{name} -> {target} (io does not import {other})")
            elif (own == "stages" and other == "stages" and name != "hbvs_cli.stages.demo"
                  and target not in ("hbvs_cli.stages", name)
                  and target.split(".")[2] not in STAGE_HELPERS):
                found.append(f"{name} -> {target} (a stage does not import another stage)")
    return found


def test_the_import_rules_hold():
    assert violations() == []


def test_the_rule_reader_sees_relative_and_function_level_imports(tmp_path, monkeypatch):
    source = "from ..core import camera\nfrom . import topics\n\ndef f():\n    from ..stages.fit import run_fit\n    import hbvs_cli.errors\n"
    probe = tmp_path / "hbvs_cli" / "io" / "probe.py"
    probe.parent.mkdir(parents=True)
    probe.write_text(source)
    monkeypatch.setattr("test_layers.REPO", tmp_path)
    assert imported_modules(probe) >= {"hbvs_cli.core", "hbvs_cli.core.camera", "hbvs_cli.io", "hbvs_cli.io.topics",
                                       "hbvs_cli.stages.fit", "hbvs_cli.errors"}


def _string_constants(tree: ast.AST) -> list[ast.Constant]:
    docstrings = {
        id(node.body[0].value) for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)
    }
    return [node for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings]


def test_topic_and_schema_names_are_spelled_once_in_io_topics():
    from hbvs_cli.io import topics

    names = {value for key, value in vars(topics).items()
             if key.isupper() and isinstance(value, str) and (key.endswith("_TOPIC") or key.endswith("_SCHEMA") or key.endswith("_METADATA"))}
    assert len(names) >= 20
    spelled = []
    for path in SOURCES:
        if path == PACKAGE / "io" / "topics.py":
            continue
        for node in _string_constants(ast.parse(path.read_text(), str(path))):
            if node.value in names:
                spelled.append(f"{module_name(path)}:{node.lineno} {node.value!r}")
    assert spelled == []
