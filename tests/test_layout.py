"""The package's layout reads like the method (issue 37): one subpackage per stage, imports that run downward only.

Stages, from the bottom: the tables between the rules (``tables``: each declared once, with its writer and
reader), the shared helpers (``plots``; ``progress``, a long job's progress in its log), then model -> solvers ->
offline -> data -> rig -> identify -> diagnose -> report (``peers``, beside the solvers: our model and solvers held
against another program's, ROSS's fault simulations, a harness the tests and benchmarks use and no stage imports;
``rig``, the virtual rig, writes records from a solved truth: it reads plans and writes records in the data stage's
formats and runs the solvers, and no stage below it imports it; both issue 52), the front door (``settings``: the
config's sections as typed objects, their defaults the schema's; then ``config``: reading and checking the config),
the twin online (``online``: a built twin judging new records, which reads the twin's own config through
``config``) and on top the command line (``cli``). A module may import from its own stage and from the stages below
it, never from a later one; an import inside a function counts too (it runs back up just the same), and so does one
under ``if TYPE_CHECKING:`` (an annotation that names a later stage's type says the code belongs to that stage:
model/sensor's two tables of a solved steady state moved to the command line for it). The test reads the source
(ast), so it needs no import to succeed to say what is wrong."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "hybridtwin"
ORDER = ["tables", "plots", "progress", "model", "solvers", "peers", "offline", "data", "rig", "identify", "diagnose", "report", "settings",
         "config", "online", "cli"]
#: the stages that are packages (folders); the others are single modules
PACKAGES = ["model", "solvers", "peers", "offline", "data", "rig", "identify", "diagnose", "report", "online", "cli"]


def _stage(module: str) -> str:
    """'hybridtwin.rig.sweep' -> 'rig'; 'hybridtwin' (the package's face) -> ''."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module imported) for every hybridtwin import in the file."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    tree = ast.parse(path.read_text())
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("hybridtwin"):
                continue
            if node.module is None or target.count(".") == 1 and target.split(".")[1] in PACKAGES:
                # "from . import x" / "from ..data import rig": the names are modules of that package
                out += [(node.lineno, f"{target}.{a.name}") for a in node.names]
            else:
                out.append((node.lineno, target))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("hybridtwin")]
    return out


def test_every_module_lives_in_a_stage_folder():
    loose = sorted(p.name for p in PACKAGE.glob("*.py")) 
    assert loose == ["__init__.py", "config.py", "plots.py", "progress.py", "settings.py", "tables.py"], loose
    assert sorted(p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__") == sorted(PACKAGES)


def test_the_rig_is_a_stage_of_its_own():
    """The virtual rig (the truth solved, records written) is not in data/, which reads measurements only: its
    modules live in rig/, and no data module imports them (issue 52)."""
    assert not list((PACKAGE / "data").glob("rig*.py"))
    assert {p.name for p in (PACKAGE / "rig").glob("*.py")} >= {"rig.py", "sweep.py", "base.py"}
    wrong = [f"{path.relative_to(PACKAGE)}:{line} imports {target}" for path in sorted((PACKAGE / "data").rglob("*.py"))
             for line, target in imports(path) if _stage(target) == "rig"]
    assert not wrong, "data/ imports the rig:\n" + "\n".join(wrong)


def test_no_stage_imports_the_peers():
    """The comparisons with another program (peers/: ROSS's fault simulations beside ours) are a harness for the
    tests and benchmarks, not a step of the method: no module outside peers/ imports them (issue 52)."""
    wrong = [f"{path.relative_to(PACKAGE)}:{line} imports {target}" for path in sorted(PACKAGE.rglob("*.py"))
             if _stage(_module_name(path)) != "peers" for line, target in imports(path) if _stage(target) == "peers"]
    assert not wrong, "modules that import the peers' harness:\n" + "\n".join(wrong)


def test_imports_run_downward_only():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        here = _stage(_module_name(path))
        if not here:  # the package's face re-exports the public names
            continue
        for line, target in imports(path):
            there = _stage(target)
            if there and ORDER.index(there) > ORDER.index(here):
                wrong.append(f"{path.relative_to(PACKAGE)}:{line} ({here}) imports {target} ({there})")
    assert not wrong, "imports that run back up:\n" + "\n".join(wrong)


#: the most lines a module of the package may have: a longer one holds more than one responsibility (issue 37)
MAX_LINES = 700


def test_no_module_is_over_700_lines():
    long = {str(p.relative_to(PACKAGE)): n for p in PACKAGE.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, (f"modules over {MAX_LINES} lines (split each into modules of one responsibility in its stage "
                      f"folder): {long}")


def test_the_public_names_come_from_the_package_itself():
    import hybridtwin

    for name in ("Machine", "Model", "Variant", "Effect", "Parameter", "Shaft", "solve", "solve_sweep",
                 "builtin_effects", "builtin_variant"):
        assert hasattr(hybridtwin, name), name


def test_no_import_circles():
    """No module imports, directly or through others, a module that imports it (at module level or inside a
    function: either runs at some point)."""
    graph = {}
    for path in PACKAGE.rglob("*.py"):
        name = _module_name(path)
        modules = {_module_name(p) for p in PACKAGE.rglob("*.py")}
        graph[name] = {t for _, t in imports(path) if t in modules and t != name and not name.startswith(t + ".")
                       and not t == name.rsplit(".", 1)[0]}
    circles, state = [], {}

    def visit(node, stack):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                circles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not circles, "\n".join(circles)


def test_every_module_imports():
    """Every module of the package imports (a relative import left pointing into the wrong folder fails here, not
    in the middle of a workflow run)."""
    import importlib
    import pkgutil

    import hybridtwin

    failed = {}
    for info in pkgutil.walk_packages(hybridtwin.__path__, "hybridtwin."):
        if info.name.endswith("__main__"):
            continue
        try:
            importlib.import_module(info.name)
        except Exception as err:  # noqa: BLE001 (every failure is reported)
            failed[info.name] = repr(err)
    assert not failed, failed


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_module_imports_another_modules_private_names():
    """A leading underscore says "this module's own": no module of the package imports such a name from another
    (``from .x import _helper``) or reaches it through the other module (``x._helper``); a helper two modules share
    is public in the one that owns it (issue 52). Attributes of objects (``self._cache``) are not counted."""
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text())
        modules = set()  # names bound to a module of the package in this file
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("hybridtwin")):
                wrong += [f"{path.relative_to(PACKAGE)}:{node.lineno} imports {a.name} from "
                          f"{'.' * node.level}{node.module or ''}" for a in node.names if _private(a.name)]
                modules |= {a.asname or a.name for a in node.names}
            elif isinstance(node, ast.Import):
                modules |= {a.asname or a.name for a in node.names if a.name.startswith("hybridtwin")}
        wrong += [f"{path.relative_to(PACKAGE)}:{node.lineno} reaches {node.value.id}.{node.attr}"
                  for node in ast.walk(tree) if isinstance(node, ast.Attribute) and _private(node.attr)
                  and isinstance(node.value, ast.Name) and node.value.id in modules]
    assert not wrong, "private names used outside their module:\n" + "\n".join(wrong)
