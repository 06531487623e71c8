"""The documentation: every ```python block of README.md and docs/ runs, and every public name has
an API reference entry.

The blocks of one page run in order in one namespace (like a notebook), in a fresh temporary
directory; a block preceded by the line ``<!-- no-run -->`` is skipped (the convention of
docs/contributing.md). The reference pages are generated at build time by ``tools/docs_reference.py``
(an mkdocs hook); the test reads what it generates. ``mkdocs build --strict`` itself runs in
``.ci/run``.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

import grasp_jax

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))
NO_RUN = "<!-- no-run -->"
_FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line, code)`` of each ```python block not marked ``<!-- no-run -->``."""
    out = []
    for m in _FENCE.finditer(text):
        before = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1].strip()
        if before == NO_RUN:
            continue
        out.append((text.count("\n", 0, m.start()) + 1, m.group(1)))
    return out


def test_blocks_are_found():
    text = "a\n```python\nx = 1\n```\n<!-- no-run -->\n```python\nraise SystemExit\n```\n```bash\nls\n```\n"
    assert python_blocks(text) == [(2, "x = 1\n")]


#: The pages with a block to run.
RUN = [p for p in PAGES if python_blocks(p.read_text(encoding="utf-8"))]


def test_the_readme_and_the_guides_have_blocks_to_run():
    names = {str(p.relative_to(ROOT)) for p in RUN}
    assert {"README.md", "docs/getting-started.md", "docs/guides/scoring.md"} <= names, names


@pytest.mark.parametrize("page", RUN, ids=[str(p.relative_to(ROOT)) for p in RUN])
def test_code_blocks_run(page, tmp_path, monkeypatch):
    blocks = python_blocks(page.read_text(encoding="utf-8"))
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"docs_{page.stem}"}
    for line, code in blocks:
        try:
            exec(compile(code, f"{page.relative_to(ROOT)}:{line}", "exec"), namespace)  # noqa: S102
        except Exception as e:  # noqa: BLE001
            raise AssertionError(f"the block at {page.relative_to(ROOT)}:{line} fails: {e!r}") from e


def _hook():
    spec = importlib.util.spec_from_file_location("docs_reference", ROOT / "tools" / "docs_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_public_name_has_a_reference_entry():
    hook = _hook()
    modules = hook.public_modules()
    assert modules[0] == "grasp_jax" and "grasp_jax.interactive" in modules and "grasp_jax.cli" not in modules
    index = hook.page("grasp_jax")
    missing = [name for name in grasp_jax.__all__ if f"\n::: grasp_jax.{name}\n" not in index]
    assert not missing, f"no API reference entry for {missing}"
    for module in modules[1:]:
        mod = importlib.import_module(module)
        text = hook.page(module)
        for name in getattr(mod, "__all__", ()):
            assert f"\n::: {module}.{name}\n" in text, (module, name)


def test_every_page_is_in_the_nav():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    for page in (ROOT / "docs").rglob("*.md"):
        assert str(page.relative_to(ROOT / "docs")) in config, f"{page} is not in mkdocs.yml's nav"
