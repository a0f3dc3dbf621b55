"""The transformer's cross-fade across its windows' borders at another width (a probe, not in the product):
`hypergs` with network.SEAM_BLEND set to BAND working pixels (0: each window's core cut hard, as before
session 41).

    python tools/seam_blend.py 0 eval --model hypergs_transformer VIDEOS --gaussians 1000 --grid 2 --frames 8 \
        --backend torch --json

Session 41 (the transformer's card): 16 px, the default, against 0 and 32 on the dev clips and the held-out pans.
"""
from __future__ import annotations

import sys

from hypergs_blender import network
from hypergs_blender.commands.cli import main

if __name__ == "__main__":
    network.SEAM_BLEND = float(sys.argv[1])
    sys.exit(main(sys.argv[2:]))
