from hhra_phys.cli import main

raise SystemExit(main())
