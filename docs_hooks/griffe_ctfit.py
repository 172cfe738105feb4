"""A Griffe extension for the documentation site (``mkdocs.yml``): ctfit as its reader sees it.

Griffe reads the source without running it, so two things ctfit does at run time are done here:

- **Lazy exports.** Each ``ctfit/_<concern>/__init__.py`` lists what it exports in a
  ``lazy_loader.attach(submod_attrs={module: [names]})`` table, loaded on first use. The extension
  adds those names to the subpackage as aliases of the module that defines them, so that the
  public names of ``ctfit/__init__.pyi`` (``ctfit.fit`` → ``ctfit._fitting.fit``) resolve.
- **Sphinx roles.** The docstrings name other objects as ``:func:`~ctfit.fit``` (reStructuredText,
  read by ``help()`` and IDEs as plain text). The extension writes each one as a Markdown
  cross-reference (``[`fit`][ctfit.fit]``) where the object is on the site (a public name, or a
  documented member of a public class), and as inline code otherwise (private helpers, modules,
  other packages' objects), so that every link on the site resolves.
  (The approach Griffe's maintainer suggests for this: mkdocstrings discussion 596.)
- **Examples in the text.** A doctest written in a docstring's text rather than in a numpy-style
  ``Examples`` section (which mkdocstrings shows as code) is fenced as a ``pycon`` code block;
  as plain Markdown, ``x[0]["a"]`` would read as a link.
"""

from __future__ import annotations

import ast
import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|attr|data|obj|exc|const):`(~?)([^`<>]+?)(?:\(\))?`")


def submod_attrs(module: griffe.Module) -> dict[str, str]:
    """name → submodule of a subpackage's ``lazy_loader.attach(submod_attrs=...)`` table ({} if none)."""
    if module.filepath is None or isinstance(module.filepath, list) or module.filepath.name != "__init__.py":
        return {}
    for node in ast.walk(ast.parse(module.filepath.read_text(encoding="utf-8"))):
        if isinstance(node, ast.keyword) and node.arg == "submod_attrs":
            return {name: sub for sub, names in ast.literal_eval(node.value).items() for name in names}
    return {}


def _final_path(obj) -> str | None:
    try:
        return obj.final_target.path if obj.is_alias else obj.path
    except (griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None


class CtfitSite(griffe.Extension):
    """Lazy exports as aliases; Sphinx roles as Markdown cross-references or inline code."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs) -> None:
        if pkg.name != "ctfit":
            return
        for sub in pkg.modules.values():
            for name, module in submod_attrs(sub).items():
                if name not in sub.members:
                    sub.set_member(name, griffe.Alias(name, f"{sub.path}.{module}.{name}", parent=sub))
        # canonical path → public path, for every public name (the aliases of __init__.pyi)
        self.public = {_final_path(obj): f"ctfit.{name}" for name, obj in pkg.members.items()
                       if obj.is_alias and obj.target_path.startswith("ctfit._") and obj.target_path.count(".") == 2}
        self.public.pop(None, None)
        self.collection = loader.modules_collection
        for obj in _objects(pkg):
            if obj.docstring is not None:
                text = ROLE.sub(lambda match, obj=obj: self.role(obj, match), obj.docstring.value)
                obj.docstring.value = fence_doctests(text)

    def role(self, obj, match: re.Match) -> str:
        """One ``:role:`target``` of ``obj``'s docstring, as Markdown."""
        short, target = match.group(1), match.group(2).strip()
        text = f"`{target.rsplit('.', 1)[-1] if short else target}`"
        link = self.site_path(obj, target)
        return f"[{text}][{link}]" if link else text

    def site_path(self, obj, target: str) -> str | None:
        """The path of ``target`` (as written in ``obj``'s docstring) on the site, or None when the
        site does not document it."""
        head, _, rest = target.partition(".")
        if head != "ctfit":
            try:
                head = obj.resolve(head)
            except griffe.NameResolutionError:
                return None
            target = f"{head}.{rest}" if rest else head
        parts = target.split(".")
        for cut in range(len(parts), 1, -1):
            try:
                found = self.collection[".".join(parts[:cut])]
            except KeyError:
                continue
            public = self.public.get(_final_path(found))
            if public is None:
                continue  # a member of a public class, or not on the site
            path = ".".join([public, *parts[cut:]])
            return path if self.documented(path) else None
        return None

    def documented(self, path: str) -> bool:
        """Is ``path`` (a public name or a member of one) rendered: public, with a docstring."""
        try:
            obj = self.collection[path]
        except KeyError:
            return False
        member = path.removeprefix("ctfit.")
        return "." not in member or (not obj.name.startswith("_") and obj.docstring is not None)


def fence_doctests(text: str) -> str:
    """``text`` with each doctest paragraph before its ``Examples`` section in a ``pycon`` fence."""
    lines, out, block = text.split("\n"), [], []
    for i, line in enumerate(lines):
        if line.strip() == "Examples" and i + 1 < len(lines) and set(lines[i + 1].strip()) == {"-"}:
            return "\n".join(out + _fenced(block) + lines[i:])
        if block and not line.strip():
            out += _fenced(block) + [line]
            block = []
        elif block or (line.lstrip().startswith(">>>") and (not out or not out[-1].strip())):
            block.append(line)
        else:
            out.append(line)
    return "\n".join(out + _fenced(block))


def _fenced(block: list[str]) -> list[str]:
    return ["```pycon", *block, "```"] if block else []


def _objects(obj):
    """``obj`` and every object defined under it (aliases left out: their targets are visited where defined)."""
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _objects(member)
