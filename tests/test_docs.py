"""The documentation: README.md is the front door, docs/ holds the reference, and the option
tables in docs/ are what the commands define (``tools/docs_options.py`` regenerates them)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"


def _docs_options():
    spec = importlib.util.spec_from_file_location(
        "docs_options", ROOT / "tools" / "docs_options.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


docs_options = _docs_options()


def _pages() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def test_option_tables_match_the_commands():
    stale = [str(path.relative_to(ROOT)) for path in docs_options.stale_pages()]
    assert not stale, f"stale option tables in {stale}: run python tools/docs_options.py --write"


def test_every_command_page_has_its_tables():
    specs = {
        match["spec"]
        for path in DOCS.glob("*.md")
        for match in docs_options.BLOCK.finditer(path.read_text())
    }
    assert {
        "t2m.sample:SampleConfig",
        "t2m.edit.__main__:EditConfig t2m.edit.request:EditRequest,unset",
        "t2m.serve.__main__:ServeConfig",
        "t2m.train.__main__:parser",
        "t2m.evaluate.__main__:parser",
    } <= specs


def test_a_table_is_regenerated_from_its_dataclass():
    page = "intro\n<!-- options dataset_tools.synth.cli:SynthConfig -->\n| old |\n<!-- /options -->\nend\n"
    fresh = docs_options.render(page)
    assert fresh != page and "| old |" not in fresh
    assert "| `--clips CLIPS` | number of clips (default: 2000) |" in fresh
    assert "| `--out OUT` | output folder |" in fresh
    assert fresh.startswith("intro\n") and fresh.endswith("<!-- /options -->\nend\n")
    assert docs_options.render(fresh) == fresh


def test_nodefault_shows_a_field_without_its_dataclass_default():
    table = docs_options.options_table("dataset_tools.build:BuildConfig,nodefault=workers")
    row = next(line for line in table.splitlines() if line.startswith("| `--workers"))
    assert "(default:" not in row
    assert "| `--max-seconds MAX_SECONDS` |" in table and "(default: 10.0)" in table


def test_a_marker_naming_nothing_is_an_error():
    with pytest.raises(LookupError, match="no_such_module"):
        docs_options.options_table("no_such_module:Config")


def test_readme_is_a_front_door():
    lines = README.read_text().splitlines()
    assert len(lines) <= 300
    linked = set(re.findall(r"\]\(docs/([\w.-]+\.md)\)", README.read_text()))
    assert linked == {path.name for path in DOCS.glob("*.md")}, "every docs page linked"


@pytest.mark.parametrize("page", _pages(), ids=lambda path: path.name)
def test_relative_links_resolve(page):
    for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        assert (page.parent / target.split("#")[0]).exists(), f"{page.name}: {target}"


@pytest.mark.parametrize("page", _pages(), ids=lambda path: path.name)
def test_shown_commands_exist(page):
    for module in set(re.findall(r"python -m ([a-z_][\w.]*[a-z_])", page.read_text())):
        assert importlib.util.find_spec(module) is not None, f"{page.name}: python -m {module}"
    makefile = (ROOT / "Makefile").read_text()
    for target in set(re.findall(r"(?:`|^)make ([a-z][\w-]*)", page.read_text(), re.MULTILINE)):
        assert re.search(rf"^{target}:", makefile, re.MULTILINE), f"{page.name}: make {target}"


# performance.md holds the benchmark figures and is revised with them (its wording and the
# module names it cites are not checked here).
OWN_PAGES = [page for page in _pages() if page.name != "performance.md"]


@pytest.mark.parametrize("page", OWN_PAGES, ids=lambda path: path.name)
def test_pages_speak_of_the_software_not_of_its_making(page):
    text = page.read_text()
    for phrase in (r"\bsessions?\b", r"\bwe\b", r"\btried\b", r"\bthe lead\b"):
        assert not re.search(phrase, text, re.IGNORECASE), f"{page.name}: {phrase}"


FILE_SUFFIXES = {"zip", "npy", "npz", "pt", "tar", "json", "md", "txt", "png", "bvh", "glb"}


def _resolves(dotted: str) -> bool:
    """Whether ``a.b.c`` names a module, or an attribute chain of the longest module prefix."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            if not hasattr(target, name):
                return False
            target = getattr(target, name)
        return True
    return False


@pytest.mark.parametrize("page", OWN_PAGES, ids=lambda path: path.name)
def test_named_files_and_modules_exist(page):
    text = page.read_text()
    for path in set(re.findall(r"`((?:t2m|dataset_tools|tests|tools)/[\w/.-]*\w/?)`", text)):
        assert (ROOT / path).exists(), f"{page.name}: {path}"
    for dotted in set(re.findall(r"`((?:t2m|dataset_tools)\.[\w.]*\w)", text)):
        if dotted.rpartition(".")[2] not in FILE_SUFFIXES:
            assert _resolves(dotted), f"{page.name}: {dotted}"


def test_readme_layout_names_every_module():
    """README's "What is where" names each module and folder directly under dataset_tools/ and
    t2m/, and nothing that is gone."""
    text = README.read_text()
    block = text[text.index("## What is where") :]
    block = block[block.index("```\n") + 4 :]
    block = block[: block.index("```")]
    named: dict[str, set[str]] = {}
    package = None
    for line in block.splitlines():
        if not line.startswith(" "):
            package = line.split()[0].rstrip("/")
            continue
        names = re.findall(r"(?<![\w./-])(\w+\.py|\w+/)(?![\w/])", line)
        named.setdefault(package, set()).update(names)
    for package in ("dataset_tools", "t2m"):
        present = {
            entry.name + ("/" if entry.is_dir() else "")
            for entry in (ROOT / package).iterdir()
            if entry.name not in ("__init__.py", "__main__.py", "__pycache__")
            and (entry.is_dir() or entry.suffix == ".py")
        }
        assert named[package] == present, (package, named[package] ^ present)


# Each table's marker and the command whose --help it mirrors.
COMMANDS = {
    "dataset_tools.build:BuildConfig,nodefault=workers": "dataset_tools.build",
    "dataset_tools.synth.cli:SynthConfig": "dataset_tools.synth.cli",
    "t2m.train.__main__:parser": "t2m.train.__main__",
    "t2m.demo:DemoConfig": "t2m.demo",
    "t2m.sample:SampleConfig": "t2m.sample",
    "t2m.edit.__main__:EditConfig t2m.edit.request:EditRequest,unset": "t2m.edit.__main__",
    "t2m.serve.__main__:ServeConfig": "t2m.serve.__main__",
    "t2m.evaluate.__main__:parser": "t2m.evaluate.__main__",
    "t2m.evaluate.mocap_bench:MocapBenchConfig": "t2m.evaluate.mocap_bench",
    "t2m.replay:ReplayConfig": "t2m.replay",
}


def _option_flags(text: str) -> set[str]:
    """The option flags in ``text`` but the negative --no-x, help and the commands' -v."""
    flags = set(re.findall(r"(?<![\w-])(--?[a-z][\w-]*)", text))
    return {flag for flag in flags if not flag.startswith("--no-")} - {
        "-h",
        "-m",
        "-v",
        "--verbose",
    }


@pytest.mark.parametrize("spec", COMMANDS)
def test_a_table_lists_the_options_of_its_command(spec, capsys, monkeypatch):
    """The marker mirrors how the command assembles its parser: the same options (a dataclass
    added to the command, or a hand-made option, shows up here)."""
    monkeypatch.setenv("COLUMNS", "1000")
    main = importlib.import_module(COMMANDS[spec]).main
    with pytest.raises(SystemExit):
        main(["--help"])
    cells = re.findall(r"^\| `([^`]*)`", docs_options.options_table(spec), re.MULTILINE)
    usage = capsys.readouterr().out.split("\n\n")[0]
    assert _option_flags(usage) == _option_flags(" ".join(cells))
    specs = {
        match["spec"]
        for path in DOCS.glob("*.md")
        for match in docs_options.BLOCK.finditer(path.read_text())
    }
    assert spec in specs
