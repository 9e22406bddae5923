"""The one table of actor kinds: the spec, the YAML schema, the world builder and
ground truth read every kind from here.

A new kind of an existing body family (``depotbench.sim.kinds``) is its entry of
numbers (``depotbench.sim.animals``) and one line in ``BUILTIN``. ``register`` adds a
kind at run time (tests, plug-ins); such a kind lives in this process only, so suites
that generate in spawned workers need it in ``BUILTIN``.
"""

from __future__ import annotations

from depotbench.sim import animals
from depotbench.sim.kinds import ActorKind, PersonBody, Place

BUILTIN: tuple[ActorKind, ...] = (
    ActorKind("person", "person", PersonBody()),
    ActorKind("sitting_person", "person", PersonBody(), Place.DESK),
    ActorKind("chair_pusher", "person", PersonBody(), Place.CHAIR),
    animals.DOG,
    animals.CAT,
    animals.PIG,
    animals.PIGEON,
)
"""Every kind a scenario may name, in the order errors and help list them."""

_KINDS: dict[str, ActorKind] = {kind.name: kind for kind in BUILTIN}


def names() -> tuple[str, ...]:
    """The kinds' names, built-in first, then those registered, in order."""
    return tuple(_KINDS)


def kinds() -> tuple[ActorKind, ...]:
    return tuple(_KINDS.values())


def get(name: str) -> ActorKind:
    """The kind called ``name``; a ValueError listing the known ones if there is none."""
    try:
        return _KINDS[name]
    except (KeyError, TypeError):
        raise ValueError(f"actor kind {name!r} is not one of {names()}") from None


def register(kind: ActorKind) -> ActorKind:
    """Add a kind at run time; a name already taken is refused."""
    if not isinstance(kind, ActorKind):
        raise TypeError(f"register takes an ActorKind, got {type(kind).__name__}")
    if kind.name in _KINDS:
        raise ValueError(f"actor kind {kind.name!r} is already registered")
    _KINDS[kind.name] = kind
    return kind


def unregister(name: str) -> None:
    """Remove a kind ``register`` added (the built-in ones stay)."""
    if any(kind.name == name for kind in BUILTIN):
        raise ValueError(f"actor kind {name!r} is built in")
    if name not in _KINDS:
        raise ValueError(f"actor kind {name!r} is not registered")
    del _KINDS[name]
