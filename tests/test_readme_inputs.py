"""The table of accepted inputs (docs/input_checks.md, "What inputs are accepted"; the README points to it),
walked row by row: each row names the tests that show what it says, and each of those tests exists. A row
added to the table without a test, or a test renamed away from its row, fails here."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The document that holds the table.
TABLE_DOC = ROOT / "docs" / "input_checks.md"

#: Table row (its first cell starts with this) -> the tests that show it ("file::function").
ROWS = {
    "quads, n-gons": ["test_obj.py::test_read_keeps_polygons_and_triangulates",
                      "test_obj.py::test_write_like_source_changes_only_vertex_lines"],
    "OBJ fields separated by any spaces/tabs": [
        "test_careless_inputs.py::test_bom_tabs_and_indentation_read_the_same_mesh",
        "test_careless_inputs.py::test_only_the_coordinates_change_colours_latin1_and_all_other_bytes_stay"],
    "missing, unreadable, binary": ["test_obj.py::test_missing_file_and_binary_file",
                                    "test_obj.py::test_bad_files_name_the_file_and_problem",
                                    "test_careless_inputs.py::test_damaged_files_are_refused_with_the_line",
                                    "test_obj_corruption.py::test_damaged_obj_is_read_right_or_refused"],
    "a file cut off": ["test_careless_inputs.py::test_a_cut_off_garment_is_refused_on_the_command_line",
                       "test_obj_corruption.py::test_cut_at_a_line_break_inside_the_faces_is_the_one_undetectable_cut"],
    "source and target bodies of different meshes where one mesh is needed": [
        "test_transfer.py::test_bodies_of_different_topology_are_refused",
        "test_careless_inputs.py::test_evaluate_with_a_body_of_another_topology",
        "test_careless_inputs.py::test_one_body_mirrored_and_the_other_not_is_named",
        "test_careless_inputs.py::test_a_mirror_image_by_vertex_order_is_not_the_same_mesh"],
    "a target body that is the source's mesh written triangulated": [
        "test_careless_inputs.py::test_faces_split_tells_a_tiling_of_the_polygons_from_other_faces",
        "test_careless_inputs.py::test_a_body_written_triangulated_is_the_same_body"],
    "a target body subdivided over the source's mesh": [
        "test_careless_inputs.py::test_a_target_given_with_the_cage_it_subdivides_is_solved_on_the_cage",
        "test_careless_inputs.py::test_the_command_line_takes_the_cage_of_a_subdivided_target",
        "blender/test_registration_operator.py::"
        "test_a_target_under_a_subdivision_surface_is_dressed_on_the_mesh_it_subdivides",
        "blender/test_registration_operator.py::"
        "test_a_target_sculpted_with_a_multiresolution_is_dressed_on_its_base_mesh_unless_the_sculpt_is_another_body",
        "blender/test_motion.py::"
        "test_a_sculpted_character_its_multiresolution_before_its_armature_is_dressed_on_its_base_mesh",
        "blender/test_outfit_operator.py::test_an_outfit_onto_a_target_under_a_subdivision_surface"],
    "a source body written triangulated and a target body of its mesh": [
        "test_careless_inputs.py::test_common_polygons_of_two_splits_of_one_mesh",
        "test_careless_inputs.py::test_a_body_written_triangulated_is_the_same_body",
        "blender/test_registration_operator.py::test_a_target_with_a_triangulate_modifier_is_the_source_mesh"],
    "a body whose faces point inward": [
        "test_careless_inputs.py::test_orientation_of_a_body_with_reversed_winding",
        "test_careless_inputs.py::test_reversed_winding_bodies_give_the_same_transfer_and_evaluation",
        "test_careless_inputs.py::test_a_body_written_with_the_other_winding_is_the_same_body",
        "test_registration.py::test_bodies_with_inward_faces_are_fitted_as_the_same_bodies_facing_outward",
        "blender/test_careless_blender.py::test_negative_scale_parent_keeps_the_garment_outside_the_body"],
    "a garment far from the source body": ["test_transfer.py::test_garment_far_from_the_body_is_refused"],
    "a garment not around its body": [
        "test_careless_inputs.py::test_garment_moved_or_turned_away_from_its_body_is_refused",
        "test_careless_inputs.py::test_makehuman_garments_pass_and_misplaced_ones_do_not"],
    "a garment whose every face has zero area": ["test_broken_meshes.py::test_all_zero_area_garment_is_refused"],
    "zero-area and needle faces": ["test_broken_meshes.py::test_zero_area_needle_duplicate_and_loose"],
    "a few loose vertices": ["test_broken_meshes.py::test_zero_area_needle_duplicate_and_loose"],
    "non-manifold edges": ["test_broken_meshes.py::test_non_manifold_and_disconnected_pieces",
                           "test_broken_meshes.py::test_flipped_faces_give_nearly_the_same_result"],
    "a garment whose pieces are not joined at their seams": [
        "test_transfer.py::test_a_garment_whose_pieces_are_not_joined_is_transferred_as_the_joined_one_with_its_seams_closed",
        "test_careless_inputs.py::test_a_garment_whose_pieces_are_not_joined_keeps_its_seams_closed_and_is_transferred_as_the_joined_one",
        "test_careless_inputs.py::test_a_garment_whose_pieces_are_not_joined_keeps_its_seams_closed_in_a_pose_and_as_an_outer_layer",
        "test_result_check.py::test_a_garment_whose_pieces_are_not_joined_has_its_seams_measured_on_the_result_and_said_when_opened",
        "test_rigging.py::test_a_garment_whose_pieces_are_not_joined_is_weighted_as_the_joined_one",
        "blender/test_transfer_operator.py::test_a_garment_in_pieces_not_joined_at_their_seams_keeps_them_closed"],
    "a body's animation given as a point cache (`shapes --target-cache BODY.pc2`) of another mesh, in other units "
    "or scaled, or with a coordinate that is not a number; a posed `--target-body` in other units or scaled; a cache "
    "that is neither PC2 nor MDD, or a `--cache` named for the other format": [
        "test_pose_fit.py::test_a_body_cache_that_is_not_the_bodys_animation_is_refused_naming_it"],
    "body weights (`weights`, Rig to Body) that leave part of the garment with no weight": [
        "test_rigging.py::test_cloth_left_with_no_weight_is_counted_and_said_and_none_weighted_is_said_so",
        "test_weights_cli.py::test_weights_that_leave_cloth_unweighted_are_said_in_the_json_and_weights_that_move_nothing_are_refused",
        "blender/test_motion.py::test_rig_to_body_says_where_the_bodys_weights_leave_the_cloth_unweighted_and_refuses_weights_that_move_nothing"],
    "a garment slightly inside the body": ["test_broken_meshes.py::test_garment_inside_the_body_is_pushed_out"],
    "open bodies": ["test_broken_meshes.py::test_bodies_with_holes",
                    "test_geometry.py::test_penetration_counted_on_closed_and_open_bodies"],
    "`--offset` / Penetration Offset": [
        "test_careless_inputs.py::test_offset_out_of_range",
        "test_careless_inputs.py::test_offset_checked_in_the_core_for_every_caller",
        "test_careless_inputs.py::test_numeric_options_out_of_range_are_usage_errors",
        "blender/test_careless_blender.py::test_offset_out_of_range_is_refused_like_on_the_command_line"],
    "`--model` or `--target` without `--method`": [
        "test_careless_inputs.py::test_model_or_target_implies_the_model_method"],
    "a model file for another source body": ["test_model.py::test_model_for_another_source_body",
                                             "test_model.py::test_unknown_target_lists_the_known_ones",
                                             "test_model.py::test_object_arrays_are_refused",
                                             "test_model.py::test_other_bad_files"],
    "an output (`--out`, `--log`, `--blend`, a model file, a results folder) that is an input": [
        "test_nothing_lost.py::test_an_output_pointed_at_an_input_is_refused_before_any_work",
        "test_nothing_lost.py::test_a_batch_results_folder_that_holds_an_input_is_refused",
        "test_nothing_lost.py::test_missing_file_in_the_way_and_read_only_places_are_refused_before_any_work",
        "test_nothing_lost.py::test_the_blender_batch_script_refuses_outputs_on_its_inputs_before_blender_starts",
        "test_careless_inputs.py::test_out_equal_to_an_input_is_refused",
        "test_careless_inputs.py::test_out_reaching_an_input_through_a_symlink_or_hard_link_is_refused",
        "test_careless_inputs.py::test_out_that_is_not_a_regular_file_is_refused",
        "test_careless_inputs.py::test_out_in_a_missing_or_read_only_folder_or_empty_names_the_users_path",
        "blender/test_careless_blender.py::test_batch_outputs_are_checked_before_the_run"],
    "huge meshes": ["test_proximity.py::test_large_queries_split_over_threads_give_the_one_piece_answer"],
    "an interrupted training, write or run": [
        "test_careless_inputs.py::test_ctrl_c_is_one_line_exit_130_and_no_file",
        "test_careless_inputs.py::test_output_files_get_the_umask_permissions",
        "test_model.py::test_cancel_writes_nothing",
        "test_obj.py::test_failed_write_leaves_the_old_file_and_no_temporary"],
}


def readme_rows():
    """First cells of the rows of the "What inputs are accepted" table in docs/input_checks.md."""
    text = TABLE_DOC.read_text(encoding="utf-8")
    section = text.split("## What inputs are accepted", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith("| ---")]
    return [r.split(" | ", 1)[0][2:].strip() for r in rows[1:]]


def test_every_readme_row_has_its_tests_and_every_listed_row_is_in_the_readme():
    rows = readme_rows()
    assert len(rows) >= 15
    unmatched = [r for r in rows if not any(r.startswith(k) for k in ROWS)]
    assert not unmatched, f"rows of {TABLE_DOC.name} without tests: {unmatched}"
    stale = [k for k in ROWS if not any(r.startswith(k) for r in rows)]
    assert not stale, f"rows no longer in {TABLE_DOC.name}: {stale}"


def test_every_named_test_exists():
    missing = []
    for tests in ROWS.values():
        for ref in tests:
            file, name = ref.split("::")
            tree = ast.parse((ROOT / "tests" / file).read_text(encoding="utf-8"))
            if not any(isinstance(n, ast.FunctionDef) and n.name == name for n in tree.body):
                missing.append(ref)
    assert not missing, missing
