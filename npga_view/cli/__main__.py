"""`python -m npga_view.cli`: the same as the `npga-view` command."""

import sys

from npga_view.cli.main import main

sys.exit(main())
