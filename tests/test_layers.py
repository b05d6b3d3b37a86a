"""Layers go one way: the core (``hrtc/``) never imports the skills (``skills/``) or a concrete task module
(``envs.cartpole``...). It may ask the task registry (``envs``: ``make``, ``names``...) for a task by name, and build
skills from configs by dotted path (Hydra's ``_target_``); every import statement counts, at module level or inside a
function, and so does ``importlib.import_module`` with a literal name."""

import ast
from pathlib import Path

import pytest

import envs

CORE = Path(__file__).resolve().parents[1] / "hrtc"
REGISTRY = {"envs", "envs.registry"}  # the task registry: lookups by name
REGISTRY_NAMES = set(envs.__all__)


def imported(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, module) for every import in ``tree``: ``from a import b`` gives ``a.b`` (b may be a module)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
        elif isinstance(node, ast.Call) and _name(node.func) == "import_module" and node.args:
            first = node.args[0]
            if isinstance(first, ast.Constant) and isinstance(first.value, str):
                found.append((node.lineno, first.value))
    return found


def _name(func: ast.expr) -> str:
    return getattr(func, "attr", getattr(func, "id", ""))


def forbidden(module: str) -> bool:
    top = module.split(".")[0]
    if top == "skills":
        return True
    if top != "envs" or module in REGISTRY:
        return False
    head, _, name = module.rpartition(".")
    return not (head in REGISTRY and name in REGISTRY_NAMES)  # `from envs import make` is a registry lookup


def violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    return [f"{path.relative_to(CORE.parent)}:{line} imports {module}" for line, module in imported(tree)
            if forbidden(module)]  # fmt: skip


def test_the_core_imports_no_skill_and_no_concrete_task():
    files = sorted(CORE.rglob("*.py"))
    assert len(files) > 20
    assert [v for path in files for v in violations(path)] == []


@pytest.mark.parametrize(
    "source,bad",
    [
        ("import skills", True),
        ("def f():\n    from skills.learned import PolicySkill", True),
        ("import skills.static as s", True),
        ("from envs import cartpole", True),
        ("def f():\n    import envs.cartpole", True),
        ("import importlib\nimportlib.import_module('envs.lunarlander')", True),
        ("import envs", False),
        ("from envs import make, names", False),
        ("from envs.registry import make", False),
        ("from hrtc.skill import Skill", False),
    ],
)
def test_the_check_sees_function_level_and_dotted_imports(source, bad):
    assert any(forbidden(module) for _, module in imported(ast.parse(source))) == bad
