"""The package layering (issue 15), checked statically: every import statement in the tree,
including those inside functions, walked with ``ast``. The table below is what each package's
docstring and docs/layout.md say it may import."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TOP = ("hil", "drivers", "virtual_robot", "profiles", "plots")
HIL_PACKAGES = ("model", "bench", "identify", "diagnose", "control", "timing", "report")
SHARED = "hil.<shared>"  # top-level hil modules the commands share (hil/cli_options.py):
# above model and bench, below the capability packages that build commands on it
ENTRY = ("hil.cli", "hil.entry", "hil.__main__")

BASE = {"hil", "drivers", "profiles"}
MAY_IMPORT: dict[str, set[str]] = {
    "profiles": set(),
    "drivers": {"profiles"},
    "plots": {"drivers", "profiles"},  # plots of recordings, for hil run and virtual-robot simulate
    "virtual_robot": {"drivers", "profiles", "plots"},
    "hil": set(),  # hil/__init__.py: the version and lazy_exports, standard library only
    # hil.model, hil.bench: their error types, for exit statuses; hil.report: --report
    SHARED: BASE | {"hil.model", "hil.bench", "hil.report"},
    "hil.report": BASE,  # HTML reports from the commands' documents (docs/reports.md)
    "hil.model": BASE,
    "hil.bench": BASE | {"plots"},  # hil run's positions.png
    # plots.layout: figure margins without a second draw
    "hil.identify": BASE | {SHARED, "hil.model", "hil.bench", "plots"},
    "hil.diagnose": BASE | {SHARED, "hil.model"},
    "hil.control": BASE | {SHARED, "hil.model", "hil.bench", "plots"},
    "hil.timing": BASE | {SHARED, "hil.model", "hil.bench", "hil.identify", "hil.control"},
    "hil.cli": BASE | {SHARED, *(f"hil.{p}" for p in HIL_PACKAGES)},
    "hil.entry": {"hil", "drivers", "hil.cli"},
    "hil.__main__": {"hil.entry"},
}

# Module cycles through imports inside functions: none (the last, openloop ↔ openloop_effects,
# went with the one stick–slip integrator). A new one must be a decision, listed here.
KNOWN_FUNCTION_LEVEL_CYCLES: list[set[str]] = []


def module_files() -> dict[str, Path]:
    mods = {}
    for top in TOP:
        for path in (ROOT / top).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            mods[name] = path
    return mods


MODULES = module_files()


def imports(name: str, *, top_level_only: bool, source: str | None = None) -> list[tuple[str, int]]:
    """(imported project module, line) for every import in module ``name`` (its file, or
    ``source``); ``from a import b`` counts as importing ``a.b`` when that is a module, else
    ``a``."""
    path = MODULES.get(name, ROOT / (name.replace(".", "/") + ".py"))
    tree = ast.parse(path.read_text() if source is None else source, str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in tree.body if top_level_only else ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, up level - 1
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:  # `import a.b.c` of a package path
                target = target.rpartition(".")[0]
            if target and target != name:
                out.append((target, node.lineno))
    return out


def unit(module: str) -> str:
    """The layer a module belongs to: a top package, a hil package, or a hil top-level module."""
    parts = module.split(".")
    if parts[0] != "hil":
        return parts[0]
    if len(parts) == 1:
        return "hil"
    if parts[1] in HIL_PACKAGES:
        return f"hil.{parts[1]}"
    if module in ENTRY:
        return module
    if (ROOT / "hil" / parts[1]).is_dir():
        raise AssertionError(
            f"hil/{parts[1]}/ is a package the layering does not know: add it to MAY_IMPORT "
            "here, to its docstring and to docs/layout.md"
        )
    return SHARED


@functools.cache
def module_imports(name: str, top_level_only: bool) -> tuple[tuple[str, int], ...]:
    return tuple(imports(name, top_level_only=top_level_only))


def graph(*, top_level_only: bool) -> dict[str, set[str]]:
    return {m: {t for t, _ in module_imports(m, top_level_only)} for m in MODULES}


def cycles(g: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(component)

    for v in sorted(g):
        if v not in index:
            visit(v)
    return found


@pytest.mark.parametrize("layer", sorted(MAY_IMPORT))
def test_each_package_imports_only_the_layers_below_it(layer):
    """profiles imports nothing of the project, drivers nothing of hil or virtual_robot, hil
    never virtual_robot, hil.model nothing of identify/diagnose/control/timing, ..."""
    wrong = [
        f"{MODULES[m].relative_to(ROOT)}:{line} imports {target}"
        for m in MODULES
        if unit(m) == layer
        for target, line in module_imports(m, False)
        if unit(target) != layer and unit(target) not in MAY_IMPORT[layer]
    ]
    assert not wrong, f"{layer} may import only {sorted(MAY_IMPORT[layer])}:\n" + "\n".join(wrong)


def test_the_html_report_is_loaded_only_when_asked():
    """Plots depend on results, not the reverse: no module outside hil.report imports it at
    its top (hil.cli_options loads it inside write_html_report, when --report is given)."""
    top = [
        f"{MODULES[m].relative_to(ROOT)}:{line}"
        for m in MODULES
        if unit(m) != "hil.report"
        for target, line in module_imports(m, True)
        if unit(target) == "hil.report"
    ]
    assert not top, "hil.report imported at module level:\n" + "\n".join(top)
    inside = {m for m in MODULES for t, _ in module_imports(m, False) if unit(t) == "hil.report"}
    assert {unit(m) for m in inside} <= {"hil.report", SHARED}


def test_every_module_is_in_a_known_layer():
    assert {unit(m) for m in MODULES} <= set(MAY_IMPORT)


def test_the_package_graph_has_no_cycle():
    units: dict[str, set[str]] = {}
    for m, targets in graph(top_level_only=False).items():
        units.setdefault(unit(m), set()).update(unit(t) for t in targets if unit(t) != unit(m))
    assert cycles(units) == []
    assert cycles(MAY_IMPORT) == []  # the allowed table itself is a DAG


def test_no_module_import_cycle():
    assert cycles(graph(top_level_only=True)) == []  # what would break an import at run time
    extra = [c for c in cycles(graph(top_level_only=False)) if c not in KNOWN_FUNCTION_LEVEL_CYCLES]
    assert not extra, f"new import cycles (counting imports inside functions): {extra}"


def test_the_walk_sees_every_kind_of_import():
    """The check is only as good as the walk: imports inside functions, relative imports and
    ``from package import module`` all count."""
    source = (
        "import numpy\n"
        "from hil.model import closed_form\n"
        "from . import tracking\n"
        "from ..bench.run import run_experiment\n"
        "def f():\n"
        "    import profiles.robot\n"
        "    from hil.identify.schemes import identify\n"
    )
    found = imports("hil.control.example", top_level_only=False, source=source)
    assert sorted(t for t, _ in found) == [
        "hil.bench.run",
        "hil.control.tracking",
        "hil.identify.schemes",
        "hil.model.closed_form",
        "profiles.robot",
    ]
    top = imports("hil.control.example", top_level_only=True, source=source)
    assert sorted(t for t, _ in top) == [
        "hil.bench.run",
        "hil.control.tracking",
        "hil.model.closed_form",
    ]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


# Parsers of recording files: numpy's and pandas' text readers and the csv module's (issue 29
# item 6: recording formats live in drivers/, the analyses read the one Recording type).
RECORDING_PARSERS = {"loadtxt", "genfromtxt", "read_csv", "read_table"}
CSV_READERS = {"reader", "DictReader"}


def recording_parsers(source: str) -> list[int]:
    """Lines of ``source`` that parse a file as a recording reader does."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            attr, base = node.func.attr, node.func.value
            csv_module = isinstance(base, ast.Name) and base.id == "csv"
            if attr in RECORDING_PARSERS or (csv_module and attr in CSV_READERS):
                lines.append(node.lineno)
    return lines


def test_recording_readers_live_in_drivers():
    """No module of the host (hil) or the robot (virtual_robot) parses a recording file itself:
    it reads drivers.recording.read_signals' Recording (drivers.one_per_line for the Panda
    log of Gaz et al.)."""
    found = {
        name: lines
        for name, path in MODULES.items()
        if name.startswith(("hil.", "virtual_robot."))
        and (lines := recording_parsers(path.read_text()))
    }
    assert not found, f"recording parsers outside drivers/ (module: lines): {found}"
    # the check sees them
    assert recording_parsers("import numpy as np\nnp.loadtxt(p)\n") == [2]
    assert recording_parsers("import csv\nrows = csv.reader(f)\n") == [2]


# Modules longer than this must say why in their docstring (issue 29: one idea per module).
MAX_MODULE_LINES = 800
LENGTH_REASON = "longer than 800 lines because"


# Over 800 lines and edited by another branch now, so the reason (or the split) comes with that
# branch's merge: the list may only shrink.
LONG_PENDING: dict[str, str] = {}  # none: selection.py is split (issue 29)


def long_modules(limit: int = MAX_MODULE_LINES) -> dict[str, int]:
    """Modules of the packages (and tests/) over ``limit`` lines whose docstring does not state
    why (the words of :data:`LENGTH_REASON` followed by the reason)."""
    paths = [*MODULES.values(), *(ROOT / "tests").rglob("*.py")]
    out = {}
    for path in paths:
        text = path.read_text()
        lines = text.count("\n")
        if lines > limit and LENGTH_REASON not in (ast.get_docstring(ast.parse(text)) or ""):
            out[str(path.relative_to(ROOT))] = lines
    return out


def test_no_module_over_800_lines_without_its_reason():
    """A module over 800 lines states why in its docstring ("longer than 800 lines because
    ..."); otherwise it is split by idea (hil/diagnose: interpret, heldout, gates, pipeline,
    report)."""
    found = long_modules()
    assert set(found) - set(LONG_PENDING) == set(), (
        f"modules over {MAX_MODULE_LINES} lines without '{LENGTH_REASON} ...' in their "
        f"docstring (lines): { {k: v for k, v in found.items() if k not in LONG_PENDING} }"
    )
    done = set(LONG_PENDING) - set(found)
    assert not done, f"{sorted(done)} now short or with its reason: take it off LONG_PENDING"
    assert long_modules(limit=0)  # the check sees modules


# isinstance on an arm model class outside hil/model/ (issue 29 item 1: the code outside asks
# the model through its interface, never its class). The ones below are still there, to go
# with the model protocol's work; the count per module may only fall, and no module may
# start one.
MODEL_ISINSTANCE_LEFT: dict[str, int] = {}  # none: hil.model.protocol.ArmDynamics answers


def model_classes() -> set[str]:
    """The arm model classes: the classes of hil/model/ named for an arm (ArmModel,
    UrdfArmModel, the open-loop simulator's arms)."""
    names = set()
    for name, path in MODULES.items():
        if name.startswith("hil.model."):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and "Arm" in node.name:
                    names.add(node.name)
    return names


def isinstance_on(source: str, classes: set[str]) -> list[int]:
    """Lines of ``source`` with isinstance/issubclass against one of ``classes`` (by name or
    attribute, alone or in a tuple)."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if not (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("isinstance", "issubclass")
            and len(node.args) == 2
        ):
            continue
        kinds = node.args[1].elts if isinstance(node.args[1], ast.Tuple) else [node.args[1]]
        for kind in kinds:
            named = kind.id if isinstance(kind, ast.Name) else getattr(kind, "attr", None)
            if named in classes:
                lines.append(node.lineno)
                break
    return lines


def test_no_isinstance_on_model_classes_outside_hil_model():
    """Outside hil/model/ no module branches on an arm model's class (isinstance/issubclass
    on ArmModel, UrdfArmModel, ...): beyond the ones MODEL_ISINSTANCE_LEFT still lists, none."""
    classes = model_classes()
    assert {"ArmModel", "UrdfArmModel"} <= classes
    found = {
        name: lines
        for name, path in MODULES.items()
        if not name.startswith("hil.model") and (lines := isinstance_on(path.read_text(), classes))
    }
    over = {
        name: lines
        for name, lines in found.items()
        if len(lines) > MODEL_ISINSTANCE_LEFT.get(name, 0)
    }
    assert not over, f"isinstance on a model class outside hil/model/ (module: lines): {over}"
    # the check sees them, alone, as an attribute and in a tuple
    source = "isinstance(m, ArmModel)\nisinstance(m, (int, model.UrdfArmModel))\nisinstance(m, X)\n"
    assert isinstance_on(source, classes) == [1, 2]


def test_drivers_draw_nothing():
    """Plots live above drivers/ (plots/, hil/*/plots.py): no drivers module imports matplotlib."""
    found = [
        f"{MODULES[name].relative_to(ROOT)}"
        for name in MODULES
        if unit(name) == "drivers" and "matplotlib" in MODULES[name].read_text()
    ]
    assert not found, f"matplotlib in drivers/: {found}"


# A name one module uses from another is public API of its module (issue 29): no module of the
# project imports a sibling's ``_private`` name (``from hil.diagnose.heldout import _masks``) or
# reads one through an imported module (``heldout._masks``). An exception is listed here, as
# "importing module: module._name" with its reason.
PRIVATE_IMPORTS_ALLOWED: dict[str, str] = {}


def private_imports(name: str, source: str | None = None) -> list[str]:
    """``line: module.name`` for every ``_private`` name of another project module that module
    ``name`` (its file, or ``source``) imports or reads as an attribute of a module it
    imported; dunder names (``__version__``) are public."""
    path = MODULES.get(name, ROOT / (name.replace(".", "/") + ".py"))
    tree = ast.parse(path.read_text() if source is None else source, str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]

    def private(attr: str) -> bool:
        return attr.startswith("_") and not attr.startswith("__")

    found, bound = [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            if base.split(".")[0] not in TOP:
                continue
            for a in node.names:
                if f"{base}.{a.name}" in MODULES:
                    bound[a.asname or a.name] = f"{base}.{a.name}"
                elif private(a.name) and base != name:
                    found.append(f"{node.lineno}: {base}.{a.name}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in TOP and a.asname:
                    bound[a.asname] = a.name
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in bound
            and private(node.attr)
        ):
            found.append(f"{node.lineno}: {bound[node.value.id]}.{node.attr}")
    return found


def test_no_module_imports_a_private_name_of_another():
    """A ``_name`` is its module's own: what a sibling module needs has a public name (every
    package of the project: hil/, drivers/, virtual_robot/, profiles/, plots/)."""
    found = {
        f"{MODULES[m].relative_to(ROOT)}:{hit}"
        for m in MODULES
        for hit in private_imports(m)
        if f"{m}: {hit.partition(': ')[2]}" not in PRIVATE_IMPORTS_ALLOWED
    }
    assert not found, "private names imported from another module:\n" + "\n".join(sorted(found))
    stale = [
        k
        for k in PRIVATE_IMPORTS_ALLOWED
        if not any(
            hit.partition(": ")[2] == k.partition(": ")[2]
            for hit in private_imports(k.partition(": ")[0])
        )
    ]
    assert not stale, f"allowed private imports no longer made: take them off: {stale}"
    # the check sees them: from-imports (relative too, inside functions), module attributes
    source = (
        "from hil.diagnose.heldout import _masks, simulated_segments\n"
        "from . import heldout\n"
        "from .heldout import __doc__\n"
        "def f():\n"
        "    from ..model.params import _read_object\n"
        "    return heldout._extras, heldout.simulated_segments\n"
    )
    assert private_imports("hil.diagnose.example", source=source) == [
        "1: hil.diagnose.heldout._masks",
        "5: hil.model.params._read_object",
        "6: hil.diagnose.heldout._extras",
    ]


# hil/diagnose's selection, split by capability (issue 29): each module imports only those
# before it, and none the diagnosis stages built on it (their docstrings say so).
SELECTION_MODULES = (
    "hil.diagnose.candidates",
    "hil.diagnose.problem",
    "hil.diagnose.physical",
    "hil.diagnose.selection",
)
DIAGNOSIS_STAGES = ("interpret", "heldout", "gates", "report", "pipeline", "drift", "effects")


def test_the_selection_modules_import_only_those_before_them():
    wrong = []
    for i, m in enumerate(SELECTION_MODULES):
        for target, line in module_imports(m, False):
            later = target in SELECTION_MODULES[i + 1 :]
            stage = target.split(".")[2:3] and target.split(".")[2] in DIAGNOSIS_STAGES
            if target.startswith("hil.diagnose.") and (later or stage):
                wrong.append(f"{MODULES[m].relative_to(ROOT)}:{line} imports {target}")
    assert not wrong, "\n".join(wrong)


# The refit's candidate vocabulary is one interface (issue 29: one effect = one module): outside
# hil/diagnose/kinds/ no module decides by a candidate's kind name (``cand.kind == "gain"``,
# ``c.kind in TERMS``); it asks the kind (``cand.spec.is_gain``, ``cand.spec.model_term``).
KINDS_PACKAGE = "hil.diagnose.kinds"


def kind_name_comparisons(source: str) -> list[int]:
    """Lines of ``source`` that compare a ``.kind`` attribute (==, !=, in, not in)."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare) and any(
            isinstance(side, ast.Attribute) and side.attr == "kind"
            for side in [node.left, *node.comparators]
        ):
            lines.append(node.lineno)
    return lines


def test_the_diagnosis_asks_a_candidate_kind_not_its_name():
    found = {
        name: lines
        for name, path in MODULES.items()
        if name.startswith("hil.diagnose.")
        and not name.startswith(KINDS_PACKAGE)
        and (lines := kind_name_comparisons(path.read_text()))
    }
    assert not found, f"kind names compared outside {KINDS_PACKAGE} (module: lines): {found}"
    # the check sees them, on either side, in a chain of conditions too
    source = (
        'if cand.kind == "gain":\n    pass\n'
        'x = a.cand.kind in ("rate", "gain")\n'
        'y = "angle" != c.kind\n'
        "z = kind == 'lag'\n"
        "w = s[0].kind not in TERMS or cand.spec.is_gain\n"
    )
    assert kind_name_comparisons(source) == [1, 3, 4, 6]
