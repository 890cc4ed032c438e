"""``python -m icprl_lightning ...`` is ``icprl ...``: the same front door where the script is not on PATH."""

from icprl_lightning.commands import main

main()
