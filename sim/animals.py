"""The animals a scenario may hold, as numbers: one ``ActorKind`` each.

A new animal of an existing body family is one entry here and one line in
``actor_registry.BUILTIN``. Each number that was tuned says what it is for; the
recognition figures behind them (YOLOX-nano on dog_and_cat_roaming and pig_pen) are
in docs/recognition.md.
"""

from __future__ import annotations

from depotbench.sim.kinds import ActorKind, BirdBody, Coat, QuadrupedBody

DOG = ActorKind(
    "dog",
    "dog",
    QuadrupedBody(
        # Legs about as long as the chest is deep and the head carried up on a neck: a
        # dog's outline, not a horse's (long legs) or a table's (head at the back's height).
        half_m=(0.3, 0.12, 0.14),
        leg_m=0.34,
        stride_m=0.6,
        tail_m=0.3,
        tail_rise=0.8,
        head_rise=0.75,
        # Thick at the root and carried in a rising sweep (level out of the rump, then up
        # behind it, as a dog walking at ease carries it): a straight, thin tail makes a
        # side-on dog read as a cow (0.81 of dogs found with the sweep).
        tail_radius=0.36,
        tail_bends=((0.55, 0.05), (0.95, 0.35), (0.9, 0.75)),
        coat=Coat(
            # Plain, dark to mid coats only: a patched dog reads as a cow or a bench, a
            # pale or cream one side-on as a sheep; the golden is a deep one for that
            # reason (recognised alone in 285 of 360 views). Cube-mapped, not laid on
            # along the body: among other animals a dog is found in more sightings so
            # (0.84 of them).
            colours=(
                ((150, 105, 60), "plain"),
                ((190, 125, 55), "plain"),
                ((35, 30, 28), "plain"),
                ((60, 45, 35), "saddle"),
                ((165, 90, 50), "plain"),  # red (setter)
                ((120, 75, 45), "plain"),
            ),
        ),
    ),
)

CAT = ActorKind(
    "cat",
    "cat",
    QuadrupedBody(
        # As deep as its legs are long, and broad: a slim cat reads as a dog, bird or
        # horse from most sides.
        half_m=(0.21, 0.1, 0.11),
        leg_m=0.19,
        stride_m=0.35,
        tail_m=0.3,
        tail_rise=1.2,
        head_rise=0.5,
        # A large head for the body, a flat face with round whisker pads under wide-set
        # amber eyes: a cat's face is wider than tall (0.63 of cats found with this head).
        skull=(1.012, 1.045, 0.968),
        muzzle=0.25,
        muzzle_radius=0.32,
        ears="erect",
        ear_height=1.05,
        ear_width=0.36,
        cheeks=True,
        eye_radius=0.15,
        iris=True,
        # Out behind the body, dipping a little, then curving up to an upright tip, as a
        # walking cat carries it (a straight stick reads as a pole).
        tail_radius=0.16,
        tail_bends=((0.45, -0.1), (0.8, 0.25), (0.8, 0.65)),
        leg_radius=0.3,
        coat=Coat(
            # Every cat wears the photographed tabby fur ('photo'), in warm colours a shade
            # lighter than real coats: drawn stripes read as a bird, a dark cat on the dark
            # floor as a shadow, a saturated ginger as a dog (0.41 of sightings found), a
            # white one as a bird. Laid on along the body at 1.0 m a texture width, the
            # photograph's stripes fall a few centimetres apart, as a tabby's do (a lone cat
            # recognised in 116 of 120 views; 88 cube-mapped).
            colours=(
                ((155, 130, 90), "photo"),
                ((210, 160, 110), "photo"),
                ((165, 130, 95), "photo"),
                ((125, 105, 75), "photo"),
            ),
            laid_on_m=1.0,
        ),
    ),
)

PIG = ActorKind(
    "pig",
    "pig",
    QuadrupedBody(
        half_m=(0.45, 0.22, 0.22),
        leg_m=0.34,
        stride_m=0.6,
        tail_m=0.09,
        tail_rise=0.8,
        barrel=True,
        skull=(0.75, 0.62, 0.68),
        muzzle=1.0,
        muzzle_radius=0.45,
        nose_at=(0.85, 0.0),
        nose=(0.2, 0.95, 0.85),
        ears="floppy",
        ear_size=1.5,
        ear_lean=0.25,
        tail_radius=0.12,
        leg_radius=0.42,
        hooves=True,
        coat=Coat(
            # Farm pigs: pink, muddy pink, ginger (Tamworth) and black (Berkshire). Clean
            # pink alone, under the wide lamps, reads as skin: a pink pig head-on was called
            # a person in 36 of 58 sightings.
            colours=(
                ((230, 165, 150), "dirt"),
                ((235, 175, 165), "plain"),
                ((185, 105, 60), "plain"),
                ((45, 40, 42), "plain"),
            ),
        ),
    ),
)

PIGEON = ActorKind("bird", "bird", BirdBody())
