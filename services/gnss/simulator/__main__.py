"""python -m viena.services.gnss.simulator: serve one GNSS twin (see serve.py)."""
import sys

from .serve import main

sys.exit(main())
