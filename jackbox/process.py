"""How a jackbox program ends: at once, once its work is done and written.

Python's own shutdown frees every module and every library Numba loaded, one
object at a time: 70-90 ms after a warm ``jackbox run`` (0.5 s in all), 0.3 s
after a helper process compiled the exact loop, for memory the system takes
back anyway. :func:`end` runs the exit handlers (:mod:`atexit`: a cache folder
of this process removed, Numba's own), flushes the streams and ends the
process with ``os._exit``. Where another Python thread is still alive (a Dask
client's), or the handlers cannot be run, it leaves the ending to Python's own
exit, which waits for that thread.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading


def end(code: int) -> None:
    """End this process with exit status `code` (see the module's text); never returns."""
    run_handlers = getattr(atexit, "_run_exitfuncs", None)
    if run_handlers is None or threading.active_count() > 1:
        sys.exit(code)
    run_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):      # a closed pipe: what was not read is lost, as at any exit
            pass
    os._exit(code)
