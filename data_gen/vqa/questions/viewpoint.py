"""Viewpoint: what is visible, how much, and the camera's angle and lens."""

from __future__ import annotations

from data_gen.vqa.questions.registry import Context, question
from data_gen.vqa.rules import NotAnswerable, Question, integer_question, label_options, pick

MOST_VISIBLE_GAP = 1.2
OCCLUSION_BINS = ((25.0, "less than 25 %"), (65.0, "between 25 % and 65 %"), (95.0, "between 65 % and 95 %"),
                  (101.0, "95 % or more"))  # fmt: skip
ANGLE_BINS = ((-60.0, "bird's-eye view"), (-15.0, "high angle"), (15.0, "eye level"), (60.0, "low angle"),
              (91.0, "worm's-eye view"))  # fmt: skip
ANGLE_MARGIN_DEG = 2.0
"""Skip cameras within this many degrees of an angle bin's edge."""
LENS_BINS = ((100.0, "ultra-wide-angle lens"), (60.0, "wide-angle lens"), (20.0, "normal lens"), (0.0, "telephoto lens"))


@question("F_VISIBILITY_OBJECT")
def most_visible(ctx: Context) -> Question:
    ids = ctx.view.visible_ids(ctx.frame)
    if not ids:
        raise NotAnswerable("nothing_visible")
    pixels = sorted(((ctx.view.state(ctx.frame, i).visible_pixels, i) for i in ids), reverse=True)
    if len(pixels) > 1 and pixels[0][0] < MOST_VISIBLE_GAP * pixels[1][0]:
        raise NotAnswerable("most_visible_not_unique")
    best = pixels[0][1]
    # distractors are objects NOT in the scene, so only the one present could be right
    return Question("Which of these objects can be seen in the image?", ctx.name(best),
                    pick(ctx.library_names_not_in_scene(), [ctx.name(best)], ctx.rng), best, "", (best,), "visible")


@question("F_VISIBILITY_OBJECT_COUNT")
def visible_count(ctx: Context) -> Question:
    n = len(ctx.view.visible_ids(ctx.frame))
    return integer_question("How many objects can be seen (not counting the floor, walls or furniture)?", n,
                            tuple(ctx.view.visible_ids(ctx.frame)), "count")


@question("F_OCCLUSION_PERCENTAGE_OBJECT")
def occlusion(ctx: Context) -> Question:
    ids = [i for i in ctx.view.visible_ids(ctx.frame) if ctx.view.name(i) is not None]
    target = ctx.target(ids)  # a partly hidden object can be asked about: visible, not necessarily 90 %
    hidden = 100.0 * (1.0 - ctx.view.state(ctx.frame, target).visible_fraction)
    label = next(lab for edge, lab in OCCLUSION_BINS if hidden < edge)
    return Question(f"How much of the {ctx.name(target)} is hidden from view?", label,
                    label_options(label, [lab for _, lab in OCCLUSION_BINS], ctx.rng), round(hidden, 2), "%",
                    (target,), f"{target}")  # fmt: skip


@question("F_VIEWPOINT_CAMERA_ANGLE")
def camera_angle(ctx: Context) -> Question:
    pitch = ctx.view.camera_pitch_deg(ctx.frame)
    if any(abs(pitch - edge) < ANGLE_MARGIN_DEG for edge, _ in ANGLE_BINS[:-1]):
        raise NotAnswerable("pitch_near_a_bin_edge")
    label = next(lab for edge, lab in ANGLE_BINS if pitch <= edge or (edge == 15.0 and pitch < edge))
    return Question("From which angle was this image taken?", label,
                    label_options(label, [lab for _, lab in ANGLE_BINS], ctx.rng), round(pitch, 2), "deg", (),
                    "camera")  # fmt: skip


@question("F_FOCAL_LENGTH_CLASS")
def lens(ctx: Context) -> Question:
    fov = ctx.view.fov_x_deg(ctx.frame)
    label = next(lab for edge, lab in LENS_BINS if fov >= edge)
    return Question("What kind of lens does the camera most likely have?", label,
                    label_options(label, [lab for _, lab in LENS_BINS], ctx.rng), round(fov, 2), "deg", (), "lens")
