from adaptfilt.cli import main

raise SystemExit(main())
