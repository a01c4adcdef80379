"""``python -m toggle_cli``: the ``toggle`` command."""

import sys

from toggle_cli import main

sys.exit(main())
