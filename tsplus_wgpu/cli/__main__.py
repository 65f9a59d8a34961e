"""``python -m tsplus_wgpu.cli``: the same as ``tsplus``."""

import sys

from .main import main

sys.exit(main())
