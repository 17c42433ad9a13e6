"""The public names of riskplan, as the API reference and the numpydoc test read them.

A public module is ``riskplan`` or a module or package under it whose dotted path has no
``_``-prefixed part, outside the application layer (``app``, ``bench``, ``commands``,
``cli``, ``__main__``). A public name is a name in the ``__all__`` of a public module (dunder
names such as ``__version__`` aside). One object exported by several public modules (a package
re-exporting its module's function, ``riskplan`` re-exporting a package's) is one public name
with several paths; the reference documents it once, at one of them: its package where the
package exports it, else its module."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from functools import cache

import riskplan

APPLICATION = {"app", "bench", "commands", "cli", "__main__"}


@cache
def public_modules() -> tuple[str, ...]:
    """Dotted names of the public modules, packages before their modules."""
    names = ["riskplan"]
    for info in pkgutil.walk_packages(riskplan.__path__, "riskplan."):
        parts = info.name.split(".")[1:]
        if parts[0] in APPLICATION or any(p.startswith("_") for p in parts):
            continue
        names.append(info.name)
    return tuple(names)


@cache
def public_names() -> dict[tuple[str, int], list[str]]:
    """Each public object, keyed by (name, id), with every public path it has."""
    groups: dict[tuple[str, int], list[str]] = {}
    for modname in public_modules():
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", ()):
            if name.startswith("__"):
                continue
            obj = getattr(mod, name)
            groups.setdefault((name, id(obj)), []).append(f"{modname}.{name}")
    return groups


def documented_at(paths: list[str]) -> set[str]:
    """Where the reference may document the public object of ``paths``: one of its public
    paths, or where it is defined (a module without ``__all__`` whose package does not export
    the object, e.g. a kernel re-exported by a facade module)."""
    modname, _, name = paths[0].rpartition(".")
    obj = getattr(importlib.import_module(modname), name)
    home, qual = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    extra = {f"{home}.{qual}"} if isinstance(home, str) and home.startswith("riskplan") else set()
    return set(paths) | extra


def public_callables():
    """(path, function) for every public function and every public method of a public class;
    the path is the object's first public path below ``riskplan`` itself (packages come
    before their modules)."""
    for (_, _), paths in public_names().items():
        path = next((p for p in paths if p.count(".") > 1), paths[0])
        modname, _, name = path.rpartition(".")
        obj = getattr(importlib.import_module(modname), name)
        if inspect.isfunction(obj):
            yield path, obj
        elif inspect.isclass(obj):
            for m, v in vars(obj).items():
                if m.startswith("_"):
                    continue
                if isinstance(v, (classmethod, staticmethod)):
                    v = v.__func__
                if inspect.isfunction(v):
                    yield f"{path}.{m}", v
