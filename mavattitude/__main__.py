"""`python -m mavattitude` is the `mavattitude` command."""

from mavattitude.cli import main

raise SystemExit(main())
