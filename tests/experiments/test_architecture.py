"""The layer rule of docs/architecture.md, read from the source (ast), and the registry against the files.

Layers, bottom to top: the core; the paper envs (with the registry and the shims); the policies (scripted in
``baselines/``, learned in ``agents/``, siblings that do not import each other); the experiments. A module may
import its own layer and the layers below, never above, and the imports form no circle.

The folders ``agents/`` and ``baselines/`` install as the packages ``mrcomm_agents`` and ``mrcomm_baselines``
(pyproject.toml), the names every import uses.
"""

from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path

import networkx as nx
import pytest

from mrcomm_env.registry import ENTRIES

if sys.version_info >= (3, 11):
    import tomllib
else:  # the dev extra installs tomli there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
#: import name → folder
FOLDERS = {"mrcomm_env": "mrcomm_env", "mrcomm_baselines": "baselines", "mrcomm_agents": "agents"}
PACKAGES = tuple(FOLDERS)


def layer(module: str) -> tuple[int, str]:
    """(rank, family) of one of our modules: rank orders the layers, family tells siblings apart."""
    if module == "mrcomm_env.core" or module.startswith("mrcomm_env.core."):
        return 0, "core"
    if module == "mrcomm_env.experiments" or module.startswith("mrcomm_env.experiments."):
        return 3, "experiments"
    if module.split(".")[0] in ("mrcomm_baselines", "mrcomm_agents"):
        return 2, module.split(".")[0]
    return 1, "envs"


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    parts[0] = {folder: name for name, folder in FOLDERS.items()}.get(parts[0], parts[0])
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def all_imports(path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, module, names taken from it) of every import in ``path``, relative imports resolved."""
    tree = ast.parse(path.read_text(), str(path))
    here = module_name(path).split(".") if path.is_relative_to(ROOT) else [path.stem]
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((node.lineno, name, tuple(alias.name for alias in node.names)))
    return found


def our_imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of one of our packages in ``path``, relative imports resolved."""
    return [(line, name) for line, name, _ in all_imports(path) if name.split(".")[0] in PACKAGES]


def source_files() -> list[Path]:
    folders = [ROOT / folder for folder in FOLDERS.values()]
    return [p for folder in folders if folder.is_dir() for p in sorted(folder.rglob("*.py"))]


def violations(files: list[Path]) -> list[str]:
    out = []
    for path in files:
        rank, family = layer(module_name(path))
        for line, name in our_imports(path):
            other_rank, other_family = layer(name)
            if other_rank > rank or (other_rank == rank == 2 and other_family != family):
                out.append(f"{path.relative_to(ROOT)}:{line} imports {name} ({other_family}, above {family})")
    return out


def test_no_module_imports_a_layer_above_its_own():
    assert source_files(), "no source files found"
    assert violations(source_files()) == []


def test_the_layer_check_catches_an_upward_import(tmp_path, monkeypatch):
    # a throwaway env module that reaches up into the policies and the experiments must be reported
    fake_root = tmp_path
    (fake_root / "mrcomm_env" / "fakeenv").mkdir(parents=True)
    bad = fake_root / "mrcomm_env" / "fakeenv" / "env.py"
    bad.write_text("import numpy\nfrom mrcomm_baselines.common import RandomPolicy\nfrom ..experiments import cli\n")
    monkeypatch.setitem(globals(), "ROOT", fake_root)
    found = violations([bad])
    assert len(found) == 2 and "mrcomm_baselines.common" in found[0] and "mrcomm_env.experiments" in found[1]


def test_policies_do_not_import_each_other(tmp_path, monkeypatch):
    (tmp_path / "agents").mkdir()
    bad = tmp_path / "agents" / "x.py"
    bad.write_text("from mrcomm_baselines import make_policy\n")
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    assert violations([bad])


# ------------------------------------------------------------------------- private attributes of others
#: names with a leading underscore that their owners document as public (``os._exit``; a namedtuple's methods)
PUBLIC_UNDERSCORED = {"_exit", "_asdict", "_replace", "_fields", "_make"}
#: modules that still read or write other modules' private attributes, and how many times: the batched trainer
#: driving SB3's PPO object without an env (its ``_setup_model``, ``_update_learning_rate``,
#: ``_current_progress_remaining``) and torch's ``Distribution._validate_args``. A count may only go down, and then
#: this record with it. (The copy-axis worlds read and write their envs through the envs' public ``world_*`` and
#: ``load_*`` methods.)
RECORDED_PRIVATE_ACCESS = {"agents/batched_ppo.py": 3}


def own_names(tree: ast.AST) -> set[str]:
    """Names a module defines itself: functions, classes, any name it assigns, and attributes it sets on
    ``self`` or ``cls``."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                names.add(node.attr)
    return names


def private_accesses(path: Path) -> list[str]:
    """``line: expression`` of every read or write of ``x._name`` in ``path`` where ``x`` is not ``self``, ``cls``
    or ``super()`` and the module does not define ``_name`` itself: another module's private attribute."""
    tree = ast.parse(path.read_text(), str(path))
    own = own_names(tree)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or not node.attr.startswith("_") or node.attr.startswith("__"):
            continue
        if node.attr in own or node.attr in PUBLIC_UNDERSCORED:
            continue
        base = node.value
        if isinstance(base, ast.Name) and base.id in ("self", "cls"):
            continue
        if isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id == "super":
            continue
        found.append(f"{node.lineno}: {ast.unparse(node)}")
    return sorted(found, key=lambda entry: int(entry.split(":")[0]))


def test_no_module_reaches_into_another_modules_private_attributes_beyond_the_record():
    counts = {}
    for path in source_files():
        found = private_accesses(path)
        if found:
            counts[str(path.relative_to(ROOT))] = found
    for name, found in counts.items():
        recorded = RECORDED_PRIVATE_ACCESS.get(name, 0)
        assert len(found) <= recorded, f"{name} reads or writes other modules' private attributes: {found}"
    fewer = {
        name: len(counts.get(name, [])) for name, n in RECORDED_PRIVATE_ACCESS.items() if len(counts.get(name, [])) < n
    }
    assert not fewer, f"fewer private accesses than recorded, lower RECORDED_PRIVATE_ACCESS to {fewer}"


def test_the_private_access_check_catches_a_read_and_a_write_and_spares_a_modules_own(tmp_path):
    module = tmp_path / "world.py"
    module.write_text(
        "class World:\n"
        "    def __init__(self, env):\n"
        "        self._rows = env._rows\n"  # its own name, though read from another object: spared
        "        self.phase = env._phase\n"  # another module's private attribute: reported
        "        env._clock = 0\n"  # writing one is reported too
        "        self.done = self._rows is None\n"
        "import os\n"
        "os._exit\n"
    )
    assert private_accesses(module) == ["4: env._phase", "5: env._clock"]


# ------------------------------------------------------------------------------ registry against the files
def modules_on_disk(folder: str, skip: tuple[str, ...]) -> set[str]:
    base = ROOT / folder
    prefix = module_name(base / "__init__.py")
    return {f"{prefix}.{p.stem}" for p in base.glob("*.py") if p.stem not in skip}


def test_every_env_shim_is_registered():
    shims = {f"mrcomm_env.{p.stem}" for p in (ROOT / "mrcomm_env").glob("*_v[0-9]*.py")}
    assert shims == {e.env for e in ENTRIES.values()}


def test_every_policy_module_is_registered():
    assert modules_on_disk("baselines", ("__init__", "common")) == {e.policies for e in ENTRIES.values()}


def test_every_reproduction_is_registered():
    on_disk = modules_on_disk("mrcomm_env/experiments/reproductions", ("__init__", "common"))
    assert on_disk == {e.reproduction for e in ENTRIES.values()}


@pytest.mark.parametrize("env_id", list(ENTRIES))
def test_registry_entry_modules_have_their_contract(env_id):
    item = ENTRIES[env_id]
    shim = importlib.import_module(item.env)
    assert {"parallel_env", "env", "raw_env"} <= set(vars(shim))
    assert shim.parallel_env.ENV_ID == env_id
    policies = importlib.import_module(item.policies)
    assert policies.ENV_ID == env_id and policies.DEFAULT_POLICY in policies.POLICIES
    reproduction = importlib.import_module(item.reproduction)
    assert reproduction.EXPERIMENTS and callable(reproduction.run)


def test_every_package_folder_is_installed():
    """pyproject.toml lists the packages by hand (two install under other names): every folder must be there."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(setuptools["packages"])
    on_disk = {module_name(p) for p in source_files() if p.name == "__init__.py"}
    assert listed == on_disk
    assert setuptools["package-dir"] == {name: folder for name, folder in FOLDERS.items() if name != folder}


def test_no_module_imports_the_bare_names_other_projects_own():
    """``agents`` and ``baselines`` are other projects' names on PyPI: our code imports only ``mrcomm_*``."""
    bare = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for path in source_files() + sorted((ROOT / "tests").rglob("*.py"))
        for line, name, _ in all_imports(path)
        if name.split(".")[0] in ("agents", "baselines")
    ]
    assert bare == []


# ------------------------------------------------------------------------------ no import circles
def import_graph(files: list[Path]) -> dict[str, set[str]]:
    """Module → the modules of ours it imports, anywhere in the file (inside functions too). ``from package import
    module`` depends on that module only (a package's ``__init__`` runs first whatever is imported from it);
    ``from package import name`` depends on the package."""
    modules = {module_name(path): path for path in files}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for _, imported, names in all_imports(path):
            submodules = {f"{imported}.{n}" for n in names} & modules.keys()
            targets = submodules if names and len(submodules) == len(names) else {imported, *submodules}
            graph[name] |= {t for t in targets if t in modules and t != name}
    return graph


def import_cycles(files: list[Path]) -> list[list[str]]:
    """Every circle of the import graph: each set of two or more modules that reach one another."""
    graph = nx.DiGraph([(a, b) for a, targets in import_graph(files).items() for b in targets])
    return sorted(sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1)


def test_the_import_graph_has_no_circle():
    assert import_cycles(source_files()) == []


def test_the_circle_check_catches_a_circle(tmp_path, monkeypatch):
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    package = tmp_path / "mrcomm_env" / "thing"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from mrcomm_env.thing import b\n")
    (package / "b.py").write_text("def f():\n    from mrcomm_env.thing.a import g\n")  # inside a function too
    (package / "c.py").write_text("from mrcomm_env.thing import a\n")
    assert import_cycles(sorted(package.glob("*.py"))) == [["mrcomm_env.thing.a", "mrcomm_env.thing.b"]]


# ------------------------------------------------------------------------------ imports inside functions
#: at most this many imports inside functions in the package (#44)
MAX_INNER_IMPORTS = 40
#: the inner imports that are not for an optional extra, each with why it stays inside its function
INNER_IMPORT_EXCEPTIONS = {
    ("mrcomm_env/registry.py", "mrcomm_env.core.batched"): "`import mrcomm_env` imports no env code (the registry)",
}


def optional_modules() -> set[str]:
    """The import names of the packages only an optional extra installs (pyproject.toml), the tooling extras (dev,
    docs) left out: ``stable-baselines3>=2.9,<3`` → ``stable_baselines3``, ``ray[rllib]==2.60.0`` → ``ray``."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]

    def import_name(requirement: str) -> str:
        name = requirement.split(";")[0]
        for mark in "[<>=!~ ":
            name = name.split(mark)[0]
        return name.strip().lower().replace("-", "_")

    required = {import_name(r) for r in project["dependencies"]}
    extras = {k: v for k, v in project["optional-dependencies"].items() if k not in ("dev", "docs")}
    return {import_name(r) for reqs in extras.values() for r in reqs} - required


def inner_imports(path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, module, names) of every import inside a function of ``path`` (nested functions once)."""
    tree = ast.parse(path.read_text(), str(path))
    found = {}
    for function in ast.walk(tree):
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(function):
                if isinstance(node, ast.Import):
                    for alias in node.names:
                        found[(node.lineno, alias.name)] = ()
                elif isinstance(node, ast.ImportFrom) and not node.level:
                    found[(node.lineno, node.module or "")] = tuple(alias.name for alias in node.names)
    return [(line, module, names) for (line, module), names in sorted(found.items())]


def top_level_imports(path: Path) -> set[str]:
    """The modules ``path`` imports when it is imported (its module body, ``if TYPE_CHECKING`` blocks left out),
    ``from package import module`` as the module."""
    tree = ast.parse(path.read_text(), str(path))
    out: set[str] = set()
    body = list(tree.body)
    while body:
        node = body.pop(0)
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        if isinstance(node, (ast.If, ast.Try)):
            body += (
                node.body
                + node.orelse
                + getattr(node, "finalbody", [])
                + [s for h in getattr(node, "handlers", []) for s in h.body]
            )
        elif isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out |= {node.module, *(f"{node.module}.{alias.name}" for alias in node.names)}
    return out


def needs_optional(module: str, optional: set[str], files: dict[str, Path], seen: set[str] | None = None) -> bool:
    """Whether importing ``module`` imports a package of an optional extra: itself, or one of ours that imports one
    when it is imported (following our modules' top-level imports)."""
    if module.split(".")[0] in optional:
        return True
    seen = set() if seen is None else seen
    if module in seen or module not in files:
        return False
    seen.add(module)
    return any(needs_optional(m, optional, files, seen) for m in top_level_imports(files[module]))


def inner_import_report(paths: list[Path]) -> tuple[int, list[str]]:
    """(how many imports inside functions, those not for an optional extra nor excepted)."""
    optional = optional_modules()
    files = {module_name(p): p for p in source_files()} | {module_name(p): p for p in paths}
    count, bad = 0, []
    for path in paths:
        relative = str(path.relative_to(ROOT))
        for line, module, names in inner_imports(path):
            count += 1
            targets = [f"{module}.{n}" for n in names if f"{module}.{n}" in files] or [module]
            if (relative, module) in INNER_IMPORT_EXCEPTIONS:
                continue
            if not all(needs_optional(t, optional, files) for t in targets):
                bad.append(f"{relative}:{line} imports {module} {names or ''} inside a function")
    return count, bad


def test_imports_inside_functions_are_few_and_each_for_an_optional_extra():
    count, bad = inner_import_report(source_files())
    assert bad == [], "import these at the top of their modules (a required dependency, or our own code)"
    assert count <= MAX_INNER_IMPORTS, f"{count} imports inside functions, more than {MAX_INNER_IMPORTS}"


def test_the_inner_import_check_knows_an_extra_from_a_required_package(tmp_path, monkeypatch):
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    (tmp_path / "pyproject.toml").write_text((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    package = tmp_path / "mrcomm_env" / "thing"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "twin.py").write_text("import torch\n")  # one of ours that needs the "train" extra
    (package / "plain.py").write_text("import numpy\n")
    (package / "uses.py").write_text(
        "def a():\n    import torch\n"  # an extra's package: fine
        "def b():\n    from mrcomm_env.thing import twin\n"  # ours, needing an extra: fine
        "def c():\n    import scipy.stats\n"  # required: reported
        "def d():\n    from mrcomm_env.thing import plain\n"  # ours, needing nothing optional: reported
    )
    count, bad = inner_import_report(sorted(package.glob("*.py")))
    assert count == 4
    assert [entry.split(" ")[0] for entry in bad] == ["mrcomm_env/thing/uses.py:6", "mrcomm_env/thing/uses.py:8"]


# ------------------------------------------------------------------------------ commands on their way down
def command_stops(run_function, call) -> tuple[list[str], object]:
    """``(stops, what call() returned)``. The stops are the modules of ours that ``run_function`` calls into while
    ``call()`` runs, in order, a module repeated only when the command left it for another in between (#44: "enter
    each module once on their way down"; the issue counted `mrcomm evaluate`'s as 12 stops in 6 modules, 6 of them
    returns). Only the calls ``run_function``'s own body makes count: what those modules do below is their business."""
    code, own = run_function.__code__, run_function.__module__
    stops: list[str] = []

    def profile(frame, event, arg):
        if event != "call" or frame.f_back is None or frame.f_back.f_code is not code:
            return
        module = frame.f_globals.get("__name__", "")
        if module.startswith(PACKAGES) and module != own and (not stops or stops[-1] != module):
            stops.append(module)

    sys.setprofile(profile)
    try:
        value = call()
    finally:
        sys.setprofile(None)
    return stops, value


def returns_of(stops: list[str]) -> list[str]:
    """The stops at a module the command had already called into and left."""
    return [module for i, module in enumerate(stops) if module in stops[:i]]


def test_the_stop_count_catches_a_command_that_returns_to_a_module(tmp_path, monkeypatch):
    (tmp_path / "zigzag_command.py").write_text(
        "from mrcomm_env.experiments import arguments, io\n"
        "def run():\n"
        "    arguments.parse_params(None)\n"
        "    io.json_safe(1.0)\n"
        "    io.json_safe(2.0)\n"  # the same module again at once: one stop
        "    arguments.parse_params(['a=1'])\n"  # back after leaving it: a return
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    zigzag = importlib.import_module("zigzag_command")
    stops, _ = command_stops(zigzag.run, zigzag.run)
    assert stops == [
        "mrcomm_env.experiments.arguments",
        "mrcomm_env.experiments.io",
        "mrcomm_env.experiments.arguments",
    ]
    assert returns_of(stops) == ["mrcomm_env.experiments.arguments"]


def test_evaluate_enters_each_module_once(tmp_path):
    from mrcomm_env.experiments.cli import main
    from mrcomm_env.experiments.commands import evaluate

    argv = ["evaluate", "ChannelAssociation-v0", "--policy", "coin_flip", "--episodes", "2", "--param", "max_cycles=4"]
    argv += ["--json", str(tmp_path / "eval.json"), "--video", str(tmp_path), "--quiet"]
    stops, exit_code = command_stops(evaluate.run, lambda: main(argv))
    assert exit_code == 0
    assert (tmp_path / "eval.json").exists() and list(tmp_path.glob("*.gif"))  # the whole way down was taken
    assert len(stops) >= 4 and not returns_of(stops), stops


@pytest.mark.parametrize("mode", ["new", "sweep", "resume"])
def test_train_enters_each_module_once(tmp_path, mode):
    from mrcomm_env.experiments.cli import main
    from mrcomm_env.experiments.commands import train

    argv = ["train", "ChannelAssociation-v0", "--timesteps", "64", "--param", "max_cycles=4", "--quiet"]
    if mode == "sweep":
        argv += ["--seeds", "0,1", "--workers", "1", "--out", str(tmp_path / "sweep")]
    else:
        argv += ["--out", str(tmp_path / "run")]
    if mode == "resume":  # a finished run extended: the path a resumed run takes
        assert main(argv) == 0
        argv = [*argv[:3], "20000", *argv[4:], "--resume"]  # past the first run's whole rollouts
    stops, exit_code = command_stops(train.run, lambda: main(argv))
    assert exit_code == 0
    assert len(stops) >= 4 and not returns_of(stops), stops
