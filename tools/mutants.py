"""Catalogue of planted label bugs for ``tools/mutate.py`` (``make mutate``).

Each mutant replaces one exact snippet of one file by a plausible bug: a sign flip, an off-by-one
frame, the wrong camera, a pixel shift, wrong units, a threshold, a dropped case. ``tests`` are the
default-run test files that should kill it, fastest first (pytest stops at the first failure); when
empty, the defaults of its file (``DEFAULT_TESTS``) are used. ``equivalent`` holds the reason when a
mutant cannot be told apart from the original by any test (it is then reported, not failed on).

When code moves, update the snippet here: ``tools/mutate.py`` refuses to run a catalogue whose
snippets no longer occur exactly once in their file.
"""

from __future__ import annotations

from dataclasses import dataclass

LABEL_TESTS = "tests/data_gen/test_gen_labels.py"

DEFAULT_TESTS: dict[str, tuple[str, ...]] = {
    "probes/metrics.py": ("tests/probes/test_probes_metrics.py",),
    "newtphys/consistency.py": ("tests/newtphys/test_core_consistency.py", LABEL_TESTS),
    "data_gen/pipeline.py": (LABEL_TESTS,),
    "data_gen/render/labels.py": ("tests/render/test_render_labels.py", LABEL_TESTS),
    "data_gen/vqa/generator.py": ("tests/data_gen/test_vqa_generation.py",),
    "data_gen/vqa/rules.py": ("tests/data_gen/test_vqa_generation.py",),
    "newtphys/vqa_schema.py": ("tests/newtphys/test_core_vqa_contract.py",),
    "data_gen/sim/energy/pair_contact.py": ("tests/sim/test_sim_batched_terms.py", "tests/sim/test_sim_warp_kernels.py"),
    # the solver runs the warp kernels; the torch terms are their reference in test_sim_warp_kernels
    "data_gen/sim/energy/point_terms.py": ("tests/sim/test_sim_warp_kernels.py", "tests/sim/test_sim_batched_terms.py",
                                           "tests/sim/test_sim_collision.py"),
    "data_gen/sim/energy/contact_kernels.py": ("tests/sim/test_sim_warp_kernels.py", "tests/sim/test_sim_collision.py"),
    "data_gen/sim/energy/elastic_kernel.py": ("tests/sim/test_sim_warp_kernels.py", "tests/sim/test_sim_column.py"),
    "data_gen/sim/fused_newton.py": ("tests/sim/test_sim_fused_newton.py",),
    "data_gen/sim/energy/gravity.py": ("tests/sim/test_sim_batched_terms.py", "tests/sim/test_sim_freefall.py"),
    "data_gen/sim/model.py": ("tests/sim/test_sim_batched_terms.py", "tests/sim/test_sim_freefall.py"),
    "data_gen/sim/newton.py": ("tests/sim/test_sim_batched_terms.py", "tests/sim/test_sim_freefall.py",
                               "tests/sim/test_sim_collision.py"),
    "probes/vlm/scoring.py": ("tests/probes/test_vlm_scoring.py",),
    "probes/vlm/prompting.py": ("tests/probes/vlm/test_vlm_baselines.py", "tests/probes/vlm/test_vlm_predictions.py",
                                "tests/probes/test_vlm_scoring.py"),
    "newtphys/vqa_scoring.py": ("tests/probes/vlm/test_vlm_extraction.py", "tests/probes/test_vlm_scoring.py"),
    "data_gen/sim/recording.py": (
        "tests/sim/test_sim_recording_moments.py",
        "tests/sim/test_sim_recording.py",
        "tests/sim/test_sim_rigid_stress.py",
        "tests/sim/test_sim_column.py",
        "tests/sim/test_sim_soft_stress.py",
        LABEL_TESTS,
    ),
}


@dataclass(frozen=True)
class Mutant:
    name: str
    file: str
    original: str
    replacement: str
    tests: tuple[str, ...] = ()
    equivalent: str | None = None
    """Why no test can kill it (None: it must be killed)."""

    @property
    def selected_tests(self) -> tuple[str, ...]:
        return self.tests or DEFAULT_TESTS[self.file]


PIPELINE = "data_gen/pipeline.py"
CONSISTENCY = "newtphys/consistency.py"
METRICS = "probes/metrics.py"
LABELS = "data_gen/render/labels.py"
RECORDING = "data_gen/sim/recording.py"

MUTANTS: tuple[Mutant, ...] = (
    # --- the five bugs of issue 16 ------------------------------------------------------------------
    Mutant("collision_f1_tp_over_denominator", METRICS,
           "2 * tp / denom.clamp_min(1.0)",
           "tp / denom.clamp_min(1.0)"),
    Mutant("scene_flow_scaled_0_9", PIPELINE,
           "geometry.rotate_vectors(w2c[t], disp_world)",
           "geometry.rotate_vectors(w2c[t], 0.9 * disp_world)"),
    Mutant("gravity_next_frames_camera", PIPELINE,
           "geometry.rotate_vectors(w2c[t], weight)",
           "geometry.rotate_vectors(w2c[min(t + 1, t_count - 1)], weight)"),
    Mutant("collision_map_all_false", PIPELINE,
           "maps[schema.COLLISION][t] = gather_labels(index, contact, False)",
           "maps[schema.COLLISION][t] = np.zeros((h, w), bool)"),
    Mutant("stress_sign_flipped", PIPELINE,
           "stress[sl] = tr.hydrostatic_stress_pa[t][nearest[k]]",
           "stress[sl] = -tr.hydrostatic_stress_pa[t][nearest[k]]"),
    # --- pipeline: frames, cameras, pixels, units ---------------------------------------------------
    Mutant("scene_flow_next_frames_camera", PIPELINE,
           "geometry.rotate_vectors(w2c[t], disp_world)",
           "geometry.rotate_vectors(w2c[t + 1], disp_world)"),
    Mutant("scene_flow_of_the_next_step", PIPELINE,
           "positions[t + 1] - positions[t]",
           "positions[min(t + 2, t_count - 1)] - positions[t + 1]"),
    Mutant("collision_drops_scene_contacts", PIPELINE,
           "contact[sl] = tr.contact_partner[t][nearest[k]] >= 0",
           "contact[sl] = tr.contact_partner[t][nearest[k]] > 0"),
    Mutant("collision_of_the_next_frame", PIPELINE,
           "contact[sl] = tr.contact_partner[t][nearest[k]] >= 0",
           "contact[sl] = tr.contact_partner[min(t + 1, t_count - 1)][nearest[k]] >= 0"),
    Mutant("stress_in_kilopascals", PIPELINE,
           "stress[sl] = tr.hydrostatic_stress_pa[t][nearest[k]]",
           "stress[sl] = 1e-3 * tr.hydrostatic_stress_pa[t][nearest[k]]"),
    Mutant("stress_of_the_next_frame", PIPELINE,
           "stress[sl] = tr.hydrostatic_stress_pa[t][nearest[k]]",
           "stress[sl] = tr.hydrostatic_stress_pa[min(t + 1, t_count - 1)][nearest[k]]"),
    Mutant("labels_rendered_with_previous_camera", PIPELINE,
           "index, depth = lab_r.render(g, K, w2c[t])",
           "index, depth = lab_r.render(g, K, w2c[max(t - 1, 0)])"),
    Mutant("depth_shifted_one_pixel", PIPELINE,
           "maps[schema.DEPTH][t] = depth",
           "maps[schema.DEPTH][t] = np.roll(depth, 1, axis=1)"),
    Mutant("depth_in_millimetres", PIPELINE,
           "maps[schema.DEPTH][t] = depth",
           "maps[schema.DEPTH][t] = 1e3 * depth"),
    Mutant("optical_flow_axes_swapped", PIPELINE,
           "maps[schema.OPTICAL_FLOW][t] = np.nan_to_num(of).astype(np.float32)",
           "maps[schema.OPTICAL_FLOW][t] = np.nan_to_num(of)[..., ::-1].astype(np.float32)"),
    Mutant("instances_shifted_one_pixel", PIPELINE,
           "maps[schema.INSTANCES][t] = ids",
           "maps[schema.INSTANCES][t] = np.roll(ids, 1, axis=0)"),
    Mutant("depth_at_splat_centres", PIPELINE,
           'depth_mode="surface"',
           'depth_mode="center"'),
    Mutant("amodal_with_previous_camera", PIPELINE,
           "render_group_masks(g, K, w2c[t], instance, object_ids)",
           "render_group_masks(g, K, w2c[max(t - 1, 0)], instance, object_ids)"),
    Mutant("amodal_materials_of_another_object", PIPELINE,
           "maps[schema.AMODAL_MATERIALS][t, k][masks[k]] = o.material_id",
           "maps[schema.AMODAL_MATERIALS][t, k][masks[k]] = objects[-1 - k].material_id"),
    Mutant("world_state_contacts_skip_the_scene", PIPELINE,
           "for p in np.unique(tr.contact_partner[t]) if p >= 0}",
           "for p in np.unique(tr.contact_partner[t]) if p > 0}"),
    Mutant("collision_drops_object_contacts", PIPELINE,
           "contact[sl] = tr.contact_partner[t][nearest[k]] >= 0",
           "contact[sl] = tr.contact_partner[t][nearest[k]] == 0"),
    Mutant("scene_flow_gathered_with_next_frames_index", PIPELINE,
           "gather_labels(index_all[t], positions[t + 1] - positions[t])",
           "gather_labels(index_all[t + 1], positions[t + 1] - positions[t])"),
    Mutant("optical_flow_from_next_frames_depth", PIPELINE,
           "of = optical_flow_from_scene_flow(maps[schema.DEPTH][t].astype(np.float64)",
           "of = optical_flow_from_scene_flow(maps[schema.DEPTH][t + 1].astype(np.float64)"),
    # --- consistency (also what the pipeline's optical flow is computed with) -----------------------
    Mutant("optical_flow_projected_with_current_camera", CONSISTENCY,
           "geometry.transform_points(w2c_next, moved)",
           "geometry.transform_points(w2c_t, moved)"),
    Mutant("optical_flow_pixel_centres_at_integers", CONSISTENCY,
           "return uv_next - geometry.pixel_centers(*depth.shape)",
           "return uv_next - (geometry.pixel_centers(*depth.shape) - 0.5)"),
    Mutant("gravity_check_uses_next_frames_camera", CONSISTENCY,
           "geometry.rotate_vectors(seq.world_to_camera[t], g)",
           "geometry.rotate_vectors(seq.world_to_camera[min(t + 1, ws.num_frames - 1)], g)"),
    Mutant("collision_check_blind", CONSISTENCY,
           "in_contact[o.id] = bool(o.contacts)",
           "in_contact[o.id] = True"),
    Mutant("validator_optical_flow_tolerance_5px", CONSISTENCY,
           '"optical_flow vs projected scene_flow": 0.05,',
           '"optical_flow vs projected scene_flow": 5.0,'),
    # --- label rasterizer ---------------------------------------------------------------------------
    Mutant("label_cover_alpha_0_1", LABELS,
           "LABEL_COVER_ALPHA = 0.5",
           "LABEL_COVER_ALPHA = 0.1"),
    Mutant("coverage_rows_half_pixel_up", LABELS,
           "dy = float(y) + 0.5 - m[1]",
           "dy = float(y) - m[1]"),
    Mutant("surface_depth_rays_through_pixel_corners", LABELS,
           "d = wp.vec3((float(x) + 0.5 - rays.cx) / rays.fx, (float(y) + 0.5 - rays.cy) / rays.fy, 1.0)",
           "d = wp.vec3((float(x) - rays.cx) / rays.fx, (float(y) - rays.cy) / rays.fy, 1.0)"),
    Mutant("gather_labels_ignores_background", LABELS,
           "out[~hit] = np.asarray(background, dtype=vals_np.dtype)",
           "pass"),
    # --- simulation record --------------------------------------------------------------------------
    Mutant("rigid_stress_sign_flipped", RECORDING,
           "return (virial + spin) / (3.0 * volume_m3)",
           "return -(virial + spin) / (3.0 * volume_m3)"),
    Mutant("soft_stress_sign_flipped", RECORDING,
           "stress = model.cauchy_hydrostatic(q).numpy()",
           "stress = -model.cauchy_hydrostatic(q).numpy()"),
    Mutant("contact_partners_not_recorded", RECORDING,
           '"contact_partner": partner.numpy().copy()',
           '"contact_partner": np.full_like(partner.numpy(), -1)'),
    Mutant("contact_event_frame_rounded_down", RECORDING,
           '"frame": -(-onset // self.substeps)',
           '"frame": onset // self.substeps'),
    Mutant("orientation_recorded_inverted", RECORDING,
           '"orientation_wxyz": matrix_to_quat_one(rotation),',
           '"orientation_wxyz": matrix_to_quat_one(rotation.T),'),
    Mutant("com_not_mass_weighted", RECORDING,
           "sums = (m[:, None] * np.concatenate(",
           "sums = (np.ones_like(m)[:, None] * np.concatenate(",
           tests=("tests/sim/test_sim_recording_moments.py",)),
    # --- solver (batched energy terms and minimiser) -----------------------------------------------
    Mutant("pair_cross_block_sign_flipped", "data_gen/sim/energy/pair_contact.py",
           "cross = -point_hessian(bi_pairs, hp_pairs, bj_pairs)",
           "cross = point_hessian(bi_pairs, hp_pairs, bj_pairs)"),
    Mutant("pair_gradient_not_on_partner", "data_gen/sim/energy/pair_contact.py",
           "grad_pts.index_add_(0, pairs.obj_j[solved_j], -(g[solved_j][:, :, None] * groups.b_j[solved_j][:, None, :]))",
           "pass"),
    Mutant("kernel_pair_cross_block_sign_flipped", "data_gen/sim/energy/contact_kernels.py",
           "add_block(hess, flat_index, island_size, b, oi, si, cols_i, oj, sj, cols_j, kp, -hs)",
           "add_block(hess, flat_index, island_size, b, oi, si, cols_i, oj, sj, cols_j, kp, hs)"),
    Mutant("kernel_pair_gradient_not_on_partner", "data_gen/sim/energy/contact_kernels.py",
           "add_gradient(grad, flat_index, b, oj, sj, cols_j, kp, -gs)",
           "add_gradient(grad, flat_index, b, oj, sj, cols_j, kp, wp.vec3d())"),
    Mutant("kernel_scene_friction_skipped_without_penetration", "data_gen/sim/energy/contact_kernels.py",
           "    if depth <= _ZERO and mu_lam <= _ZERO:\n        return 0, e, g, h, n\n    e, g, h = _penalty_and_friction(depth,",
           "    if depth <= _ZERO:\n        return 0, e, g, h, n\n    e, g, h = _penalty_and_friction(depth,"),
    Mutant("kernel_friction_pushes_along_slip", "data_gen/sim/energy/contact_kernels.py",
           "    return energy, ratio * u, hess",
           "    return energy, -ratio * u, hess"),
    Mutant("kernel_island_offset_wrong", "data_gen/sim/energy/contact_kernels.py",
           "base = row * island_size - (row // island_size) * island_size",
           "base = row * island_size - (row // island_size) * island_size * island_size"),
    Mutant("kernel_determinant_hessian_sign_flipped", "data_gen/sim/energy/elastic_kernel.py",
           "value = value + coef * _levi_civita(ri, ck) * _levi_civita(rj, cl) * f[m, nn]",
           "value = value - coef * _levi_civita(ri, ck) * _levi_civita(rj, cl) * f[m, nn]"),
    Mutant("kernel_projection_test_never_fails", "data_gen/sim/energy/elastic_kernel.py",
           "flagged = not_positive_definite(h, tolerance_pa[o])",
           "flagged = 0"),
    Mutant("kernel_projection_flip_modes_use_the_twist_sign", "data_gen/sim/energy/elastic_kernel.py",
           "flip = mu - c * sig[m]  # (E_ab + E_ba) / sqrt 2",
           "flip = mu + c * sig[m]  # (E_ab + E_ba) / sqrt 2"),
    Mutant("fused_scene_cull_ignores_motion", "data_gen/sim/fused_newton.py",
           "if st.margin[o, s] > moved * bd.b_norm[o, s]:",
           "if st.margin[o, s] > _ZERO * moved * bd.b_norm[o, s]:"),
    Mutant("fused_gravity_potential_sign_flipped", "data_gen/sim/fused_newton.py",
           "value = value - h2 * st.gravity[r] * tm[o, r, a] * bd.mass_b_sum[o, a]",
           "value = value + h2 * st.gravity[r] * tm[o, r, a] * bd.mass_b_sum[o, a]"),
    Mutant("fused_padding_not_identity", "data_gen/sim/fused_newton.py",
           "hess[base + r * n_size + r] = _ONE",
           "hess[base + r * n_size + r] = _ZERO"),
    Mutant("fused_affine_cross_block_sign_flipped", "data_gen/sim/fused_newton.py",
           "_add_affine_block(hess, n_size, matrix_base, fi - start, bi, fj - start, bj, -hs)",
           "_add_affine_block(hess, n_size, matrix_base, fi - start, bi, fj - start, bj, hs)"),
    Mutant("fused_band_ignores_pair_coupling", "data_gen/sim/fused_newton.py",
           "if oj >= 0:  # the cross blocks widen both objects' bands",
           "if oj >= 0 and oj < 0:  # the cross blocks widen both objects' bands"),
    Mutant("friction_pushes_along_slip", "data_gen/sim/energy/point_terms.py",
           "grad = ratio[:, None] * u",
           "grad = -ratio[:, None] * u"),
    Mutant("gravity_gradient_sign_flipped", "data_gen/sim/energy/gravity.py",
           "grad = -gravity_m_s2[None, :, None] * mass_b_sum[:, None, :]",
           "grad = gravity_m_s2[None, :, None] * mass_b_sum[:, None, :]"),
    Mutant("rigid_cubature_keeps_one_point_volume", "data_gen/sim/model.py",
           "cub_volume[o, 0] = m.volumes_m3.sum()",
           "cub_volume[o, 0] = m.volumes_m3[0]"),
    Mutant("newton_trust_radius_ignored", "data_gen/sim/newton.py",
           "alpha = torch.clamp(trust_m / motion.clamp(min=1e-300), max=1.0)",
           "alpha = torch.ones_like(motion)"),
    # --- VLM scoring -------------------------------------------------------------------------------
    Mutant("vlm_bootstrap_resamples_items", "probes/vlm/scoring.py",
           "            r.item.sequence_id,\n            r.item.question_id,\n            r.item.sub_category,\n"
           "            r.item.category,\n            float(bool(getattr(r, key))),",
           "            r.item.idx,\n            r.item.question_id,\n            r.item.sub_category,\n"
           "            r.item.category,\n            float(bool(getattr(r, key))),"),
    Mutant("vlm_circular_any_rotation", "probes/vlm/scoring.py",
           "cs = all(p is not None and p.letter == truth for p in rots)",
           "cs = any(p is not None and p.letter == truth for p in rots)"),
    Mutant("vlm_rotated_letter_not_mapped_back", "probes/vlm/prompting.py",
           "return vs.LETTERS[(vs.LETTERS.index(letter) + rotation) % len(vs.LETTERS)]",
           "return letter"),
    Mutant("vlm_first_letter_instead_of_last", "newtphys/vqa_scoring.py",
           '_LAST_LETTER = re.compile(r"(?:^|[^A-Za-z])([A-Da-d])$")',
           '_LAST_LETTER = re.compile(r"^([A-Da-d])(?:[^A-Za-z]|$)")'),
    # --- metrics ------------------------------------------------------------------------------------
    Mutant("f1_false_negatives_off_the_mask", METRICS,
           "fn = (~p & t & m).sum()",
           "fn = (~p & target.bool()).sum()"),
    Mutant("gravity_magnitude_error_signed", METRICS,
           "(p.norm(dim=1) - g.norm(dim=1)).abs()",
           "(p.norm(dim=1) - g.norm(dim=1))"),
    Mutant("zero_length_threshold_raised", METRICS,
           "ZERO_LENGTH_EPS: float = 1e-8",
           "ZERO_LENGTH_EPS: float = 1e-2"),
    # --- questions (VQA) ---------------------------------------------------------------------------
    Mutant("vqa_wrong_answer_letter", "data_gen/vqa/generator.py",
           'vs.AnswerRecord(record["idx"], vs.LETTERS[position], record["value"], record["unit"])',
           'vs.AnswerRecord(record["idx"], vs.LETTERS[(position + 1) % 4], record["value"], record["unit"])'),
    Mutant("vqa_multi_options_shuffled", "data_gen/vqa/generator.py",
           "options=tuple(options), objects=tuple(record[\"objects\"]),",
           "options=tuple(options if record[\"mode\"] == \"single\" else options[::-1]), "
           "objects=tuple(record[\"objects\"]),"),
    Mutant("vqa_window_off_by_one_frame", "data_gen/vqa/rules.py",
           "return [frame - (count - 1 - i) * k for i in range(count)]",
           "return [frame - (count - i) * k for i in range(count)]"),
    Mutant("vqa_wrong_aggregation_level", "newtphys/vqa_schema.py",
           '("F_KINEMATICS_SPEED_OBJECT", "kinematics", _BOTH, True),',
           '("F_KINEMATICS_SPEED_OBJECT", "collision", _BOTH, True),'),
)
