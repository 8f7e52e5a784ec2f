"""The layers are a promise, read from the source with :mod:`ast` (docs/layout.md).

- every package of ``hbvs_cli`` has a layer, and imports only from lower layers or from
  itself: errors < core < io, perception, sim < settings < report, sweep < stages < cli; packages of
  one layer (io, perception and sim; report and sweep) do not import each other;
- no stage imports another stage (the modules that run several stages aside);
- no two modules import each other, directly or through others (no cycle);
- every topic and schema name is spelled once, in ``io/topics.py``;
- no two modules share a file name.

Imports inside functions count the same as those at the top of a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from conftest import REPO

#: The layer of each part of ``hbvs_cli``: a module may import from a lower layer or from
#: its own package, never from a higher layer or from another package of its layer.
#: ``""`` is the package itself (``hbvs_cli/__init__.py``: the version), ``__main__``
#: starts the command line; ``thread_pool`` is the thread pool perception and stages share;
#: ``stop_signals`` the stop signals' exceptions the CLI raises and the stages' loops check.
LAYERS: dict[str, int] = {
    "": 0, "errors": 0, "thread_pool": 0, "stop_signals": 0,
    "core": 1,
    "io": 2, "perception": 2, "sim": 2,
    "settings": 3,
    "report": 4, "sweep": 4,
    "stages": 5,
    "cli": 6,
    "__main__": 7,
}
#: Modules of ``stages`` that are shared helpers, not subcommands: any stage may use them
#: (``live``: the loop of ``repeat --live``).
STAGE_HELPERS = ("console", "options", "frame_decoding", "live", "auto_target")
#: Modules of ``stages`` that run other stages: ``demo`` (the whole pipeline) and
#: ``sweep_run`` (one run of a sweep: repeat, then report).
STAGE_RUNNERS = ("demo", "sweep_run")


def stage_of(module: str) -> str:
    """The subcommand a module of ``stages`` belongs to: ``sweep_run`` is part of ``sweep``."""
    return module.split(".")[2].split("_")[0]


def package_root() -> Path:
    return REPO / "hbvs_cli"


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
    path = REPO.joinpath(*name.split("."))
    return path.with_suffix(".py").exists() or (path / "__init__.py").exists()


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def sources() -> list[Path]:
    return sorted(package_root().rglob("*.py"))


def import_graph() -> dict[str, set[str]]:
    """Module -> the hbvs_cli modules it imports (a package stands for its ``__init__``)."""
    graph = {module_name(path): imported_modules(path) for path in sources()}
    return {name: {target for target in targets if target in graph and target != name} for name, targets in graph.items()}


def violations() -> list[str]:
    found = []
    for path in sources():
        name = module_name(path)
        own = layer(name)
        if own not in LAYERS:
            found.append(f"{name}: the package {own!r} has no layer (add it to LAYERS and docs/layout.md)")
            continue
        for target in sorted(imported_modules(path)):
            other = layer(target)
            if other == own:
                if (own == "stages" and name.split(".")[2] not in STAGE_RUNNERS and target not in ("hbvs_cli.stages", name)
                        and target.split(".")[2] not in STAGE_HELPERS and stage_of(target) != stage_of(name)):
                    found.append(f"{name} -> {target} (a stage does not import another stage)")
            elif other not in LAYERS:
                found.append(f"{name} -> {target} (the package {other!r} has no layer)")
            elif LAYERS[other] == LAYERS[own]:
                found.append(f"{name} -> {target} ({own} and {other} are one layer: they do not import each other)")
            elif LAYERS[other] > LAYERS[own]:
                found.append(f"{name} -> {target} ({own} does not import {other}, a higher layer)")
    return found


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: its strongly connected components of two or more
    modules (Tarjan's algorithm, iterative), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
    return cycles


def test_every_package_has_its_layer():
    packages = {path.parent.name for path in package_root().glob("*/__init__.py")}
    assert packages <= set(LAYERS)
    assert {"core", "io", "perception", "sim", "report", "sweep", "stages", "cli"} <= packages


def test_the_import_rules_hold():
    assert violations() == []


def test_no_module_imports_itself_through_others():
    assert import_cycles(import_graph()) == []


def _write(root: Path, relative: str, source: str) -> Path:
    path = root / "hbvs_cli" / relative
    path.parent.mkdir(parents=True, exist_ok=True)
    for folder in path.relative_to(root).parents:
        if folder != Path("."):
            (root / folder / "__init__.py").touch()
    path.write_text(source)
    return path


def test_the_rule_reader_sees_relative_and_function_level_imports(tmp_path, monkeypatch):
    source = "from ..core import camera\nfrom . import topics\n\ndef f():\n    from ..stages.fit import run_fit\n    import hbvs_cli.errors\n"
    probe = _write(tmp_path, "io/probe.py", source)
    _write(tmp_path, "core/camera.py", "")
    _write(tmp_path, "io/topics.py", "")
    monkeypatch.setattr("test_layers.REPO", tmp_path)
    assert imported_modules(probe) >= {"hbvs_cli.core", "hbvs_cli.core.camera", "hbvs_cli.io", "hbvs_cli.io.topics",
                                       "hbvs_cli.stages.fit", "hbvs_cli.errors"}


@pytest.mark.parametrize(("relative", "source", "said"), [
    ("io/probe.py", "from ..perception import base\n", "io and perception are one layer"),
    ("sim/probe.py", "def f():\n    from ..io.images import decode_image\n", "sim and io are one layer"),
    ("report/probe.py", "from ..sweep.spec import SweepPlan\n", "report and sweep are one layer"),
    ("sweep/probe.py", "from ..stages.console import Console\n", "sweep does not import stages"),
    ("core/probe.py", "from ..io import topics\n", "core does not import io"),
    ("stages/probe.py", "from .fit import run_fit\n", "a stage does not import another stage"),
    ("extras/probe.py", "", "has no layer"),
])
def test_the_rules_catch_a_breach(tmp_path, monkeypatch, relative, source, said):
    _write(tmp_path, relative, source)
    monkeypatch.setattr("test_layers.REPO", tmp_path)
    assert any(said in line for line in violations())


def test_a_cycle_is_caught(tmp_path, monkeypatch):
    _write(tmp_path, "report/plots.py", "from .figure_style import figure_style\n")
    _write(tmp_path, "report/figure_style.py", "def figure_style():\n    from .plots import PANEL_NAMES\n")
    _write(tmp_path, "report/table.py", "from . import plots\n")
    monkeypatch.setattr("test_layers.REPO", tmp_path)
    assert import_cycles(import_graph()) == [["hbvs_cli.report.figure_style", "hbvs_cli.report.plots"]]
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


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
    for path in sources():
        if path == package_root() / "io" / "topics.py":
            continue
        for node in _string_constants(ast.parse(path.read_text(), str(path))):
            if node.value in names:
                spelled.append(f"{module_name(path)}:{node.lineno} {node.value!r}")
    assert spelled == []


def test_no_two_modules_share_a_file_name():
    """A file name says which module it is: ``camera.py`` in three packages meant three things."""
    names = [path.name for path in package_root().rglob("*.py") if path.name != "__init__.py"]
    assert sorted({name for name in names if names.count(name) > 1}) == []
