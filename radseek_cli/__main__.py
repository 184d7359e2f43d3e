"""``python -m radseek_cli``: the ``radseek`` command."""

import sys

from radseek_cli.main import main

sys.exit(main())
