"""Actor kinds are one table (depotbench.sim.actor_registry): the spec, the YAML schema,
the world builder and ground truth read it, and the schema's choices and defaults are the
spec's. A new animal of an existing family is its numbers and one entry of the table;
here a goat that exists only in this test walks into a generated sequence."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from depotbench.scenes.schema import Scenario, SpecError, parse_scenario, to_scenario
from depotbench.sim import actor_registry
from depotbench.sim import spec as sim_spec
from depotbench.sim.kinds import PRIORS, ActorKind, Coat, Place, QuadrupedBody

GOAT = ActorKind(
    "goat",
    "goat",
    QuadrupedBody(
        half_m=(0.36, 0.14, 0.17),
        leg_m=0.42,
        stride_m=0.7,
        tail_m=0.1,
        tail_rise=1.5,
        head_rise=1.0,
        skull=(0.85, 0.7, 0.75),
        muzzle=1.1,
        ears="erect",
        hooves=True,
        coat=Coat(colours=(((225, 220, 205), "plain"), ((120, 85, 55), "saddle"))),
    ),
)

GOAT_YAML = {
    "name": "goat_walk",
    "frames": 3,
    "image": {"width": 160, "height": 120},
    "intrinsics": {"fx": 131.25},
    "layout": {"rack_rows": 0, "props": 0, "desk": False},
    "actors": [{"kind": "goat", "speed_mps": 0.8, "waypoints": [[-1.2, -0.4], [1.2, -0.4]]}],
}


@pytest.fixture
def goat():
    """The goat, registered for one test (the public way of adding a kind)."""
    actor_registry.register(GOAT)
    try:
        yield GOAT
    finally:
        actor_registry.unregister(GOAT.name)


def test_an_unregistered_kind_is_refused_by_name_in_one_line():
    assert "goat" not in actor_registry.names()
    with pytest.raises(SpecError) as refused:
        parse_scenario(GOAT_YAML, "goat.yaml")
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith("goat.yaml: actors.0.kind: Input should be 'person'")
    assert "(got 'goat')" in message
    with pytest.raises(ValueError, match="actor kind 'goat' is not one of"):
        sim_spec.ActorSpec("goat")


def test_a_kind_registered_at_run_time_is_generated_with_its_class(goat, tmp_path: Path):
    from depotbench.sim.generate import generate

    assert actor_registry.names()[-1] == "goat"
    scenario = to_scenario(parse_scenario(GOAT_YAML, "goat.yaml"))
    assert [a.kind for a in scenario.actors] == ["goat"]
    out = generate(scenario, tmp_path / "goat", progress=False)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["classes"]["goat"] == "dynamic"
    (actor,) = [i for i in meta["instances"] if i["kind"] == "actor"]
    assert actor["class_name"] == "goat"
    frames = [json.loads(line) for line in (out / "gt" / "objects.jsonl").read_text().splitlines()]
    goats = [o for frame in frames for o in frame["objects"] if o["class"] == "goat"]
    assert len(goats) == 3 and all(o["box_xyxy"] is not None and o["moving"] for o in goats)
    # the spec it was generated from reads back from meta.json
    assert sim_spec.spec_from_dict(meta["scenario"]) == scenario


def test_the_schema_accepts_exactly_the_registry_kinds_and_their_paths_and_needs(goat):
    schema = Scenario.model_json_schema()["$defs"]["Actor"]["properties"]
    assert schema["kind"]["enum"] == list(actor_registry.names())
    for kind in actor_registry.kinds():
        needs = {"chair": {"chairs": [{"position_m": [2.0, -1.0]}]}, "desk": {}}.get(kind.place.needs, {})
        for path in kind.paths:
            data = {"name": "k", "actors": [{"kind": kind.name, "path": path}], **needs}
            assert to_scenario(parse_scenario(data, "k.yaml")).actors[0].kind == kind.name
        for path in set(sim_spec.PATH_MODES) - set(kind.paths):
            with pytest.raises(SpecError, match=f"actors.0: .*path '{path}' does not go with kind"):
                parse_scenario({"name": "k", "actors": [{"kind": kind.name, "path": path}]}, "k.yaml")
        if kind.place.needs == "chair":
            with pytest.raises(SpecError, match=f"chairs: a {kind.name} needs at least one chair"):
                parse_scenario({"name": "k", "actors": [{"kind": kind.name}]}, "k.yaml")
        if kind.place.needs == "desk":
            data = {"name": "k", "layout": {"desk": False}, "actors": [{"kind": kind.name, "path": "seated"}]}
            with pytest.raises(SpecError, match=f"layout.desk: a {kind.name} needs the desk"):
                parse_scenario(data, "k.yaml")


def test_the_schemas_choices_are_the_specs():
    defs = Scenario.model_json_schema()["$defs"]
    assert defs["Actor"]["properties"]["path"]["enum"] == list(sim_spec.PATH_MODES)
    assert defs["Actor"]["properties"]["clothing"]["enum"] == [*sim_spec.CLOTHING, "any"]
    assert defs["Camera"]["properties"]["motion"]["enum"] == list(sim_spec.CAMERA_MOTIONS)
    for motion in sim_spec.CAMERA_MOTIONS:
        data = {"name": "m", "camera": {"motion": motion, "position_m": [0.0, -3.0, 1.4]}}
        assert to_scenario(parse_scenario(data, "m.yaml")).camera.motion == motion
    for clothing in sim_spec.CLOTHING:
        data = {"name": "c", "actors": [{"kind": "person", "clothing": clothing}]}
        assert to_scenario(parse_scenario(data, "c.yaml")).actors[0].clothing == clothing
    low, high = sim_spec.SPEED_RANGE_MPS
    for speed, fine in ((low, True), (high, True), (high + 0.01, False)):
        data = {"name": "s", "actors": [{"kind": "dog", "speed_mps": speed}]}
        if fine:
            assert to_scenario(parse_scenario(data, "s.yaml")).actors[0].speed_mps == speed
        else:
            with pytest.raises(SpecError, match="actors.0.speed_mps"):
                parse_scenario(data, "s.yaml")


def test_a_scenario_that_sets_nothing_is_the_specs_defaults():
    """Every default a scenario file leaves out is the simulator's: what the schema emits
    for a file naming only what the spec has no default for equals the spec built from
    its own defaults (frames: the spec's 90 given, as a file's default is 10 s)."""
    kinds = actor_registry.names()
    data = {
        "name": "d",
        "frames": sim_spec.ScenarioSpec().frames,
        "actors": [{"kind": kind, "path": actor_registry.get(kind).place.paths[0]} for kind in kinds],
        "chairs": [{"position_m": [2.0, -1.0]}],
    }
    emitted = to_scenario(parse_scenario(data, "d.yaml"))
    expected = sim_spec.ScenarioSpec(
        name="d",
        actors=tuple(
            dataclasses.replace(sim_spec.ActorSpec(kind), path=actor_registry.get(kind).place.paths[0])
            for kind in kinds
        ),
        chairs=(sim_spec.ChairSpec((2.0, -1.0)),),
    )
    assert emitted == expected
    assert [a.path for a in emitted.actors if a.kind == "person"] == [sim_spec.ActorSpec("person").path]


def test_the_table_refuses_what_it_cannot_build():
    with pytest.raises(ValueError, match="already registered"):
        actor_registry.register(actor_registry.get("dog"))
    with pytest.raises(ValueError, match="built in"):
        actor_registry.unregister("dog")
    with pytest.raises(ValueError, match="cannot go to the desk"):
        ActorKind("desk_goat", "goat", GOAT.body, Place.DESK)
    with pytest.raises(ValueError, match="prior 'sometimes'"):
        ActorKind("goat2", "goat", GOAT.body, prior="sometimes")
    with pytest.raises(ValueError, match="lower case"):
        ActorKind("Goat", "goat", GOAT.body)
    assert all(kind.prior in PRIORS for kind in actor_registry.BUILTIN)
    assert len({kind.name for kind in actor_registry.BUILTIN}) == len(actor_registry.BUILTIN)
