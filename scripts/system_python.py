"""Makes sure a script that needs pyopenvdb runs under Debian's /usr/bin/python3.

pyopenvdb (python3-openvdb) and its numpy live in the system interpreter; a pyenv or
virtualenv `python3` first on PATH has neither. Importing this module (before
importing numpy or pyopenvdb) re-runs the calling script under /usr/bin/python3 in that
case, or exits with a one-line explanation.
"""

import os
import sys

try:
    import numpy  # noqa: F401
    import pyopenvdb  # noqa: F401
except ImportError:
    if os.path.realpath(sys.executable) != os.path.realpath("/usr/bin/python3") \
            and os.path.exists("/usr/bin/python3") and not os.environ.get("VDBCOOK_NO_REEXEC"):
        os.environ["VDBCOOK_NO_REEXEC"] = "1"
        os.execv("/usr/bin/python3", ["/usr/bin/python3"] + sys.argv)
    sys.exit("%s needs pyopenvdb and numpy: run it with /usr/bin/python3 (Debian's "
             "python3-openvdb)" % os.path.basename(sys.argv[0]))
