"""The shape of the code: every import of the source, those inside functions included, against the table in
docs/architecture.md ("What a module may import"); no parallel kernel with more than 12 parameters; no module
of the render path over 400 lines."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "probvis"
DOC = ROOT / "docs" / "architecture.md"
MAX_KERNEL_PARAMETERS = 12
MAX_LINES = 400
LONG_ALLOWED = ("scene.mitsuba_xml", "cli", "experiments.*")  # the XML reader, the command line, the studies


def module_name(path):
    """`visibility.occlusion_map.map` for src/probvis/visibility/occlusion_map/map.py; `probvis` for the package."""
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts) or "probvis"


def is_module(name):
    rel = Path(*name.split("."))
    return (SRC / rel).with_suffix(".py").is_file() or (SRC / rel / "__init__.py").is_file()


def imports(path):
    """(line, probvis module) of every import in the file, at any depth."""
    name = module_name(path)
    package = name.split(".") if path.name == "__init__.py" and name != "probvis" else name.split(".")[:-1]
    if name == "probvis":
        package = []
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                mod = base + (node.module.split(".") if node.module else [])
            elif node.module and (node.module == "probvis" or node.module.startswith("probvis.")):
                mod = node.module.split(".")[1:]
            else:
                continue
            for alias in node.names:  # `from .x import y` imports module x.y when y is a module
                sub = ".".join(mod + [alias.name])
                out.append((node.lineno, sub if is_module(sub) else ".".join(mod) or "probvis"))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "probvis" or alias.name.startswith("probvis."):
                    out.append((node.lineno, alias.name[len("probvis."):] or "probvis"))
    return out


def matches(name, pattern):
    if pattern.endswith(".*"):
        return name == pattern[:-2] or name.startswith(pattern[:-1])
    return name == pattern


def rules():
    """The table's rows: (module patterns, allowed patterns or None for anything)."""
    text = DOC.read_text().split("## What a module may import", 1)[1]
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else []
        if len(cells) != 2 or cells[0] in ("modules", "---"):
            continue
        modules = re.findall(r"`([^`]+)`", cells[0])
        allowed = None if cells[1].startswith("anything") else re.findall(r"`([^`]+)`", cells[1])
        rows.append((modules, allowed))
    assert rows, "docs/architecture.md has no import table"
    return rows


def row_of(name, table):
    for modules, allowed in table:
        if any(matches(name, p) for p in modules):
            return allowed
    return ()


SOURCES = sorted(SRC.rglob("*.py"))


def test_every_module_has_a_row_in_the_table():
    table = rules()
    missing = [module_name(p) for p in SOURCES if row_of(module_name(p), table) == ()]
    assert not missing, f"modules without a row in docs/architecture.md: {missing}"


def test_every_import_is_one_the_table_allows():
    table = rules()
    bad = []
    for path in SOURCES:
        name = module_name(path)
        allowed = row_of(name, table)
        if allowed is None:
            continue
        for line, target in imports(path):
            if target != name and not any(matches(target, p) for p in allowed):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not bad, "imports the layering forbids:\n" + "\n".join(bad)


def test_the_checker_sees_imports_inside_functions(tmp_path):
    """A test that cannot fail is a defect: the walk finds a nested relative import and resolves it."""
    found = imports(SRC / "integrator.py")
    assert (any(t == "scene.builtin" for _, t in found)  # imported inside the warm-up function
            and all(t == "probvis" or is_module(t) for _, t in found))
    assert not any(matches("film", p) for p in row_of("visibility.proxy", rules()))


def kernels():
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef):
                for d in node.decorator_list:
                    if isinstance(d, ast.Call) and any(k.arg == "parallel" and getattr(k.value, "value", False)
                                                       for k in d.keywords):
                        yield path, node


def test_parallel_kernels_take_named_records_not_long_argument_lists():
    found = list(kernels())
    assert len(found) > 10
    long = [f"{p.relative_to(ROOT)}:{n.lineno} {n.name} ({len(n.args.args)})" for p, n in found
            if len(n.args.args) > MAX_KERNEL_PARAMETERS]
    assert not long, f"parallel kernels with more than {MAX_KERNEL_PARAMETERS} parameters: {long}"


def test_modules_of_the_render_path_stay_short():
    long = [f"{module_name(p)} ({n})" for p in SOURCES
            if (n := len(p.read_text().splitlines())) > MAX_LINES
            and not any(matches(module_name(p), pat) for pat in LONG_ALLOWED)]
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_the_command_line_imports_scipy_only_where_used():
    """`probvis render` with exact visibility (the default) never needs scipy's kd-tree, sparse graphs or image
    labelling, which take a fifth of a second to import: importing the command line leaves them out."""
    import subprocess
    import sys

    code = ("import sys, probvis.cli; print(sorted(m for m in sys.modules if m.startswith(("
            "'scipy.spatial', 'scipy.sparse', 'scipy.ndimage'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_console_command_starts_light():
    """The console command imports neither numpy nor Numba before it can report a failed start in one line."""
    import subprocess
    import sys

    code = "import sys, probvis.__main__; print(sorted(m for m in sys.modules if m in ('numpy', 'numba')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
