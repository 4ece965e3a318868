"""The documentation: the MkDocs site builds with ``--strict`` (a broken link, anchor or mkdocstrings reference is a
warning, and strict makes it an error); the README's relative links and images point at files of the repository;
the README stays short and its test command is exactly the one ``.ci/run`` runs."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
CI_RUN = ROOT / ".ci" / "run"
MAX_README_LINES = 250

# [text](target) and ![alt](target), targets without spaces; reference-style links are not used in the README
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HTML_SRC = re.compile(r"""<(?:img|a)\b[^>]*?\b(?:src|href)=["']([^"']+)["']""", re.IGNORECASE)


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() == "true"


def require(module: str) -> None:
    """The module, or skip (locally) / fail (CI=true): the docs are built in CI."""
    try:
        found = importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # a dotted name whose parent package is missing
        found = False
    if not found:
        msg = f"{module} is not installed (pip install -e '.[test]')"
        if in_ci():
            pytest.fail(msg)
        pytest.skip(msg)


def strip_code(markdown: str) -> str:
    """The Markdown without fenced code blocks and inline code (their brackets are not links)."""
    markdown = re.sub(r"^```.*?^```", "", markdown, flags=re.DOTALL | re.MULTILINE)
    return re.sub(r"`[^`\n]*`", "", markdown)


def readme_targets() -> list[str]:
    text = strip_code(README.read_text(encoding="utf-8"))
    return LINK.findall(text) + HTML_SRC.findall(text)


def github_anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but '-' and '_' dropped, spaces -> '-'."""
    text = re.sub(r"[`*_]", lambda m: "_" if m.group() == "_" else "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The GitHub anchors of a Markdown page's headings (code blocks left out)."""
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.DOTALL | re.MULTILINE)
    return {github_anchor(m) for m in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, flags=re.MULTILINE)}


def test_mkdocs_site_builds_strict(tmp_path):
    require("mkdocs")
    require("mkdocstrings_handlers.python")
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stdout}\n{r.stderr}"
    assert "WARNING" not in r.stderr, r.stderr
    for page in ("index", "troubleshooting", "python", "api", "interactive"):
        assert (site / ("index.html" if page == "index" else f"{page}/index.html")).is_file(), page
    assert "FvizError" in (site / "api" / "index.html").read_text(encoding="utf-8"), "mkdocstrings rendered no API"
    assert (site / "img" / "main-screen.png").is_file()


def test_mkdocs_nav_lists_every_page():
    """Every Markdown page under docs/ is in the nav (strict mode only reports omitted files as info)."""
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = sorted(p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md"))
    missing = [p for p in pages if f": {p}" not in nav]
    assert not missing, f"pages not in mkdocs.yml's nav: {missing}"
    for required in ("python.md", "api.md", "interactive.md", "troubleshooting.md"):
        assert required in pages, required


def test_readme_links_and_images_resolve():
    targets = readme_targets()
    assert any(t.endswith("main-screen.png") for t in targets), "the README shows no screenshot"
    broken = []
    for target in targets:
        url = urlparse(target)
        if url.scheme or target.startswith("//"):
            continue  # absolute URLs are not checked (no network in the tests)
        path = (README.parent / unquote(url.path)).resolve() if url.path else README
        if not path.exists() or ROOT not in path.parents:
            broken.append(target)
        elif url.fragment and path.suffix == ".md" and url.fragment not in anchors(path):
            # GitHub's anchors; docs headings keep to words so that MkDocs' anchors are the same
            broken.append(f"{target} (no such heading in {path.name}; anchors: {sorted(anchors(path))})")
    assert not broken, f"README links to what the repository does not hold: {broken}"


def test_readme_images_are_small_files_in_the_repo():
    for target in readme_targets():
        if target.lower().endswith((".png", ".jpg", ".jpeg", ".gif", ".svg", ".webp")) and not urlparse(target).scheme:
            size = (README.parent / target).stat().st_size
            assert size < 500_000, f"{target}: {size} bytes"


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_README_LINES, f"README.md has {n} lines (at most {MAX_README_LINES}: the rest belongs in docs/)"


def ci_test_command() -> str:
    """The command under ``# --- the README's test command (keep identical) ---`` in .ci/run."""
    lines = CI_RUN.read_text(encoding="utf-8").splitlines()
    marker = next((i for i, line in enumerate(lines) if line.lstrip().startswith("#") and "keep identical" in line), None)
    assert marker is not None, f"{CI_RUN} has no '# --- the README's test command (keep identical) ---' line"
    return next(line.strip() for line in lines[marker + 1:] if line.strip() and not line.lstrip().startswith("#"))


def readme_set_up_commands() -> list[str]:
    """The commands of the README's "Set up" section's bash blocks, in order."""
    text = README.read_text(encoding="utf-8")
    section = re.search(r"^## Set up.*?$(.*?)(?=^## )", text, flags=re.DOTALL | re.MULTILINE)
    assert section, "README has no '## Set up' section"
    blocks = re.findall(r"^```(?:bash|sh)?\n(.*?)^```", section.group(1), flags=re.DOTALL | re.MULTILINE)
    return [line.strip() for block in blocks for line in block.splitlines() if line.strip() and not line.startswith("#")]


def test_readme_has_two_set_up_commands_and_the_test_one_is_ci_run_s():
    commands = readme_set_up_commands()
    assert len(commands) == 2, commands
    main_job, tests = commands
    assert "fviz inspect pair --synthetic" in main_job and ".rrd" in main_job, main_job
    assert tests == ci_test_command(), f"README: {tests!r}\n.ci/run: {ci_test_command()!r}"
