"""Generate a NewtPhys dataset split: ``python generate.py split=train num_sequences=100``.

The same command as the installed ``newtphys-generate`` (``data_gen.generate_cli``); see
``newtphys/conf/generate.yaml`` for every option, ``python generate.py --help`` for the config groups.
"""

from data_gen.generate_cli import main, run  # noqa: F401  (run: tests call it with a composed config)

if __name__ == "__main__":
    main()
