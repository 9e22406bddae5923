"""What a kind of actor is: plain data, read from one table (``depotbench.sim.actor_registry``).

An ``ActorKind`` names a kind (``kind:`` in a scenario), the class its instances carry
in ground truth, where it goes (``Place``) and its body. A body is one dataclass per
body family (people, four-legged animals, birds): the world builder moves and meshes
a family by the type of its body, so a new kind of an existing family is a new set of
numbers. This module holds data only (no NumPy, no MuJoCo), so that the spec and the
YAML schema can check a kind's name without loading the code that builds it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum
from typing import ClassVar

PRIORS = ("dynamic", "potential", "static")
"""How likely a class is to move, as ground truth states it."""

WALKS = ("loop", "random_walk")
"""Paths of an actor that moves about the hall: round a loop, or an open wander."""
TUM_WALK = "tum_walk"
"""A person's errands as in TUM fr3's walking sequences: across the view near the desk,
out of it and back, and to a seat at the desk to sit a few seconds (``actors.TumWalker``)."""
SEATED = "seated"
PATH_MODES = (*WALKS, TUM_WALK, SEATED)
"""Every value of an actor's ``path``."""


class Place(Enum):
    """Where a kind of actor is: what it needs of the scene, and the paths it takes."""

    HALL = "hall"
    """Along a path across the floor, drawn from the seed or given as waypoints."""
    DESK = "desk"
    """On a seat at the desk (the layout's desk, one person a seat)."""
    CHAIR = "chair"
    """To and fro over a chair, pushing it (the scenario's chairs, one each in turn)."""

    @property
    def paths(self) -> tuple[str, ...]:
        return (SEATED,) if self is Place.DESK else WALKS

    @property
    def needs(self) -> str | None:
        """What of the scene it cannot do without: 'desk', 'chair' or nothing."""
        return {Place.DESK: "desk", Place.CHAIR: "chair"}.get(self)


Colour = tuple[int, int, int]
"""An sRGB colour, 0-255 a channel."""


@dataclass(frozen=True)
class Coat:
    """An animal's coat: one of ``colours`` is drawn for each animal (``textures.coat``)."""

    colours: tuple[tuple[Colour, str], ...]
    """(colour, pattern): 'plain', 'dirt' (soft smears), 'saddle' (a dark back) or
    'photo' (the photographed tabby fur in that colour, ``textures.tabby``)."""
    laid_on_m: float | None = None
    """Metres of body one width of the texture covers, laid on along each part (texture
    coordinates round it, ``figures.wrapped``); None: cube-mapped."""


@dataclass(frozen=True)
class PersonBody:
    """A person: build, clothes and hair are drawn from the seed for each one
    (``figures.Look``), so a kind sets nothing here. Only people sit and push chairs."""

    places: ClassVar[tuple[Place, ...]] = (Place.HALL, Place.DESK, Place.CHAIR)


@dataclass(frozen=True)
class QuadrupedBody:
    """A four-legged animal's proportions (``figures.quadruped_surfaces`` meshes them,
    ``actors.Quadruped`` walks them). Lengths in metres; the factors scale the trunk's
    half-width ``half_m[1]`` unless said otherwise. Fields left out take a dog's shape."""

    places: ClassVar[tuple[Place, ...]] = (Place.HALL,)

    half_m: tuple[float, float, float]
    """Half-lengths of the trunk along, across and up."""
    leg_m: float
    """Hip to paw, standing."""
    stride_m: float
    """One gait cycle's travel; above 0.9 of it per second the animal trots."""
    tail_m: float
    tail_rise: float
    """How high the tail is carried: its bone points back + this much up."""
    coat: Coat
    head_rise: float = 0.0
    """How far a neck lifts the head above the back, in half-widths (0: no neck)."""
    barrel: bool = False
    """One round trunk (a pig's) instead of a deep chest and a narrower loin."""
    skull: tuple[float, float, float] = (0.9, 0.78, 0.8)
    """The skull's radii along, across and up."""
    muzzle: float = 1.25
    """Muzzle length (times the drawn ``AnimalLook.muzzle``)."""
    muzzle_radius: float = 0.42
    nose_at: tuple[float, float] = (0.8, 0.1)
    """The nose's centre ahead of and above the muzzle's tip, in muzzle radii."""
    nose: tuple[float, float, float] = (0.3, 0.55, 0.4)
    """The nose's radii, in muzzle radii."""
    ears: str | None = None
    """'erect' or 'floppy'; None: drawn for each animal."""
    ear_height: float = 0.75
    """An erect ear's height, in skull heights."""
    ear_width: float = 0.3
    """An erect ear's root radius, in skull widths."""
    ear_size: float = 1.0
    """A floppy ear's size, against a dog's."""
    ear_lean: float = 0.0
    """How far a floppy ear hangs forward over the face."""
    cheeks: bool = False
    """Round whisker pads under the eyes (a cat's face)."""
    tail_radius: float = 0.36
    """The tail's root radius (it tapers)."""
    tail_bends: tuple[tuple[float, float], ...] | None = None
    """A curved tail's Bezier controls after its root, in tail lengths (back, up); None:
    a straight tail along its bone."""
    leg_radius: float = 0.34
    hooves: bool = False
    """The lower legs end in dark hooves."""
    eye_radius: float = 0.09
    iris: bool = False
    """Large amber irises with dark pupils set into the skull's surface (a cat's eyes);
    otherwise small dark eyes just under the coat's surface."""

    def __post_init__(self) -> None:
        if self.ears not in (None, "erect", "floppy"):
            raise ValueError(f"ears {self.ears!r}: 'erect', 'floppy' or None (drawn)")
        if min(*self.half_m, self.leg_m, self.stride_m, self.tail_m) <= 0:
            raise ValueError("half_m, leg_m, stride_m and tail_m must be positive")


@dataclass(frozen=True)
class BirdBody:
    """A pigeon (``figures.bird_surfaces``): it hops with its wings folded and now and
    then flies a short way; its feathers are the shared ``fur_bird`` material."""

    places: ClassVar[tuple[Place, ...]] = (Place.HALL,)


Body = PersonBody | QuadrupedBody | BirdBody


@dataclass(frozen=True)
class ActorKind:
    """One kind of actor, all there is to know about it: ``actor_registry`` lists it
    once, and everything that needs a kind reads it from there."""

    name: str
    """What scenarios call it: ``kind:`` in a YAML file, ``ActorSpec.kind``."""
    class_name: str
    """The class its instances carry in boxes, masks and meta.json (a COCO class name
    where COCO has the animal, so detectors can be scored on it)."""
    body: Body
    place: Place = Place.HALL
    prior: str = "dynamic"
    """How likely the class is to move (``PRIORS``)."""

    @property
    def paths(self) -> tuple[str, ...]:
        """The values of ``path`` it takes: its place's, and for a person in the hall
        also TUM's errands (only people sit down)."""
        if self.place is Place.HALL and isinstance(self.body, PersonBody):
            return (*self.place.paths, TUM_WALK)
        return self.place.paths

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", self.name):
            raise ValueError(f"actor kind name {self.name!r}: lower case letters, digits and _ only")
        if not re.fullmatch(r"[a-z][a-z0-9_ ]{0,31}", self.class_name):
            raise ValueError(f"actor kind {self.name!r}: class name {self.class_name!r} is not a plain name")
        if self.prior not in PRIORS:
            raise ValueError(f"actor kind {self.name!r}: prior {self.prior!r} is not one of {PRIORS}")
        if not isinstance(self.body, PersonBody | QuadrupedBody | BirdBody):
            raise ValueError(f"actor kind {self.name!r}: {type(self.body).__name__} is not a body family")
        if self.place not in self.body.places:
            raise ValueError(
                f"actor kind {self.name!r}: a {type(self.body).__name__} cannot go to the {self.place.value}"
            )
