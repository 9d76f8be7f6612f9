"""``python -m ipm.cli``: the same as the ``ipm`` command."""

from ipm.cli import main

main()
