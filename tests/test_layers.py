"""The package's layers (docs/architecture.md): a package imports only the packages below it, and the
envs import nothing from the learners. Read from the source with ``ast``, imports inside functions too."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "platform" / "hingelab"
# bottom first; packages on one line (a tuple) do not import each other
LAYERS = [
    ("errors",), ("paths", "disk_full", "folder_lock", "camera", "tasks", "seeds", "safe_names", "bounded_reads",
                  "arguments", "json_text", "out_dir"),
    ("__init__",), ("provenance",),
    ("sim",), ("episodes",), ("perception",), ("analysis", "viewers", "heuristic", "workers"), ("policies",),
    ("envs",), ("rollouts",), ("robot",), ("ros2",), ("training",), ("learners",), ("sweeps",), ("bench",), ("cli",),
]
LEVEL = {name: level for level, names in enumerate(LAYERS) for name in names}


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports():
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE)
        here = relative.parts[0] if len(relative.parts) > 1 else relative.stem
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names if node.module == "hingelab"]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for target in targets:
                if target.startswith("hingelab.") or target == "hingelab":
                    yield relative, here, _part(target), node.lineno


def test_every_package_has_a_layer():
    packages = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    modules = {p.stem for p in PACKAGE.glob("*.py")}
    assert packages | modules <= set(LEVEL), f"not in a layer: {sorted((packages | modules) - set(LEVEL))}"


def test_no_import_runs_up_the_layers():
    upward = [f"{file}:{line} imports hingelab.{target} ({here} is below it)"
              for file, here, target, line in _imports()
              if here != target and target in LEVEL and LEVEL[target] >= LEVEL[here]]
    assert not upward, "\n".join(upward)


def test_the_envs_import_nothing_of_the_learners():
    assert not [(f, t) for f, here, t, _ in _imports() if here == "envs" and t in ("training", "learners")]
