"""Evaluate a vision-language model (or a baseline) on a question set:
``python evaluate_vlm.py vlm=qwen2_5_vl_7b vqa_dir=data/vqa/test``.

The same command as the installed ``newtphys-evaluate-vlm`` (``probes.vlm.cli``); options in
``newtphys/conf/evaluate_vlm.yaml``, models in ``newtphys/conf/vlm/``.
"""

from probes.vlm.cli import main, run  # noqa: F401  (run: tests call it with a composed config)

if __name__ == "__main__":
    main()
