from shadowless.cli import main

raise SystemExit(main())
