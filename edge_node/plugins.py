"""Named kinds a user picks in a config or on a command line, and that other packages can add:
detectors and re-id backends (``edge_node/perception``), topologies (``sim_cluster/network``),
sources (``edge_node/runtime/sources.py``).

A :class:`Registry` holds one family. The kinds this project ships register themselves in the
module that defines them (one ``REGISTRY.add(name, kind)`` beside the class); another package
adds a kind with one line in its ``pyproject.toml``::

    [project.entry-points."dmtt.detectors"]
    mydetector = "my_package.my_module:MyDetectorKind"

and it is then known by name everywhere a built-in one is: config validation, command-line
choices and help, error messages. Entry points are only loaded when a name is looked up or the
names are listed, so an installed plug-in costs nothing until it is used; a plug-in that
cannot be loaded is a typed error naming it, not a traceback. A built-in name cannot be taken
over by a plug-in (the built-in wins, and the listing says so).
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from importlib.metadata import EntryPoint, entry_points
from typing import Generic, TypeVar

from protocol.errors import DmttError

T = TypeVar("T")


class PluginError(DmttError, ValueError):
    """An unknown kind, or an installed plug-in that cannot be loaded."""


class Registry(Generic[T]):
    """The kinds of one family by name: the built-in ones in registration order, then those
    other packages install in the entry-point group ``group``, sorted by name.

    ``what`` names the family in messages (``"detector"``); ``error`` is the typed error an
    unknown name raises (a subclass of :class:`~protocol.errors.DmttError` taking one message).
    """

    def __init__(self, what: str, group: str, error: Callable[[str], DmttError] = PluginError):
        self.what = what
        self.group = group
        self.error = error
        self._builtin: dict[str, T] = {}
        self._loaded: dict[str, T] = {}

    def add(self, name: str, kind: T) -> T:
        """Register the built-in ``kind`` under ``name``; returns ``kind`` (usable as a
        decorator through :meth:`register`). A second kind under one name is a programming
        error."""
        if name in self._builtin:
            raise ValueError(f"{self.what} {name!r} is registered twice")
        self._builtin[name] = kind
        return kind

    def register(self, name: str) -> Callable[[T], T]:
        """``@REGISTRY.register("name")`` above a class or function."""
        return lambda kind: self.add(name, kind)

    def _entry_points(self) -> list[EntryPoint]:
        return [ep for ep in entry_points(group=self.group) if ep.name not in self._builtin]

    def builtin(self) -> tuple[str, ...]:
        """The names this project ships, in registration order."""
        return tuple(self._builtin)

    def names(self) -> tuple[str, ...]:
        """Every known name: the built-in ones, then the installed plug-ins (sorted)."""
        return self.builtin() + tuple(sorted({ep.name for ep in self._entry_points()}))

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self.names()

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def get(self, name: str) -> T:
        """The kind registered as ``name``; the family's typed error when nobody registered it
        or its plug-in cannot be loaded."""
        if name in self._builtin:
            return self._builtin[name]
        if name in self._loaded:
            return self._loaded[name]
        found = [ep for ep in self._entry_points() if ep.name == name]
        if not found:
            raise self.error(f"unknown {self.what} {name!r} (known: {', '.join(self.names())}; "
                             f"another package can add one in the entry-point group "
                             f"{self.group!r})")
        try:
            kind = found[0].load()
        except Exception as e:  # noqa: BLE001 - a broken plug-in is the user's setup, say which
            raise self.error(f"{self.what} {name!r}: its plug-in {found[0].value} cannot be "
                             f"loaded ({type(e).__name__}: {e})") from None
        self._loaded[name] = kind
        return kind
