from newtphys.cli import main

raise SystemExit(main())
