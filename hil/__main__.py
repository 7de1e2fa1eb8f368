"""`python -m hil` is the `railhil` command."""

from hil.cli.main import main

raise SystemExit(main())
