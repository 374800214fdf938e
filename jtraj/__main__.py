"""``python -m jtraj ...``: the ``jtraj`` command (`jtraj.cli`), for an environment whose
scripts folder is not on PATH."""

from jtraj.cli import main

raise SystemExit(main())
