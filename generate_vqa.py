"""Write physics questions from generated shards: ``python generate_vqa.py data_dir=data/newtphys split=test``.

The same command as the installed ``newtphys-generate-vqa`` (``data_gen.vqa.cli``); options in
``newtphys/conf/generate_vqa.yaml``.
"""

from data_gen.vqa.cli import main, run  # noqa: F401  (run: tests call it with a composed config)

if __name__ == "__main__":
    main()
