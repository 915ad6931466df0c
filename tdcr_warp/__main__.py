from tdcr_warp.cli import main

raise SystemExit(main())
