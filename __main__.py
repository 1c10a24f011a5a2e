from nearlight.cli import main

raise SystemExit(main())
