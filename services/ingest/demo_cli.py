"""``mimic demo-motion OUTDIR``: write the embedded demo motions as BVH (see :mod:`.demo_motion`)."""

from services.ingest.demo_motion import add_arguments, main

__all__ = ["add_arguments", "main"]
