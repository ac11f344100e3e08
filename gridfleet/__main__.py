"""`python -m gridfleet`: the same as the `gridfleet` command."""

import sys

from gridfleet.system.cli import main

sys.exit(main())
