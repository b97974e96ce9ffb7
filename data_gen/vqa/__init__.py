"""Physics questions generated from the world state and frames of NewtPhys shards (docs/vqa_contract.md).

``view`` reads one sequence (never re-simulates); ``rules`` holds the shared rules (visibility, frames,
distractors, letters); ``questions/`` holds one small function per question id; ``variants/`` one module per
kind of variant (ROI and location wording, masking, cues, expertise levels, counterfactuals: the only part
that simulates, opt-in); ``generator`` writes a question set. Entry point: ``python generate_vqa.py data_dir=... split=test out_dir=...``.
"""
