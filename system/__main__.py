"""`python -m system`: the same as the `gridfleet` command."""

import sys

from system.cli import main

sys.exit(main())
