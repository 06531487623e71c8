"""mkdocs hook: the API reference, generated at build time from the package itself.

One page per public module of grasp_jax (every module or subpackage whose name does not start with
an underscore, except the command line's entry points), with one mkdocstrings entry (``::: name``)
per name of the module's ``__all__`` (the whole module where it has none). ``grasp_jax`` itself
comes first: every name of ``grasp_jax.__all__``. A name added to an ``__all__``, or a new public
module (``grasp_jax/grippers/``, say), appears in the reference without editing any page.

``tests/test_docs.py`` checks that every name of ``grasp_jax.__all__`` has an entry.
"""

from __future__ import annotations

import importlib
import pkgutil
import re

#: Modules that are entry points, not an API.
SKIP = {"grasp_jax.cli", "grasp_jax.__main__"}
#: Where the generated pages go (under docs/, never written to disk).
PREFIX = "reference"


def public_modules() -> list[str]:
    """``grasp_jax`` and its public modules and subpackages, in name order after it."""
    import grasp_jax

    names = [f"grasp_jax.{m.name}" for m in pkgutil.iter_modules(grasp_jax.__path__)
             if not m.name.startswith("_")]
    return ["grasp_jax"] + sorted(n for n in names if n not in SKIP)


def page_name(module: str) -> str:
    return f"{PREFIX}/index.md" if module == "grasp_jax" else f"{PREFIX}/{module.split('.', 1)[1]}.md"


def page(module: str) -> str:
    """The markdown of one module's reference page."""
    mod = importlib.import_module(module)
    doc = (mod.__doc__ or "").strip().split("\n\n", 1)[0].replace("\n", " ")
    lines = [f"# `{module}`", ""]
    if module == "grasp_jax":
        lines += ["Every name of `grasp_jax.__all__`, generated from the docstrings at build time. "
                  "The other public modules:", ""]
        lines += [f"- [`{m}`]({page_name(m).split('/', 1)[1]})" for m in public_modules()[1:]]
        lines += [""]
    elif doc:
        lines += [doc, ""]
    names = list(getattr(mod, "__all__", ()))
    if not names:
        lines += [f"::: {module}", "    options:", "      show_root_heading: false", "      show_root_toc_entry: false", ""]
        return "\n".join(lines)
    for name in names:
        lines += [f"::: {module}.{name}", "    options:", "      show_root_heading: true",
                  "      show_root_full_path: false", ""]
    return "\n".join(lines)


def on_config(config):
    nav = config.get("nav")
    if nav is not None:
        entries = [{m: page_name(m)} for m in public_modules()]
        for item in nav:
            if isinstance(item, dict) and "API reference" in item:
                item["API reference"] = entries
                break
        else:
            nav.append({"API reference": entries})
    return config


_ROLE = re.compile(r":(?:func|class|data|attr|meth|mod|exc|obj):(?=<code|<a )")


def on_page_content(html, page, config, files):
    """Docstrings use Sphinx roles (``:func:`name```); the rendered page keeps only the name."""
    return _ROLE.sub("", html) if page.file.src_uri.startswith(PREFIX + "/") else html


def on_files(files, config):
    from mkdocs.structure.files import File

    for module in public_modules():
        files.append(File.generated(config, page_name(module), content=page(module)))
    return files
