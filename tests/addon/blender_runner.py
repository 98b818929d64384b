"""Run the add-on tests inside a real Blender (the app, not the PyPI module):

    blender -b --factory-startup --python-exit-code 1 -P tests/addon/blender_runner.py -- [pytest args]

Blender's bundled Python has numpy but not pytest or OpenEXR: install them once into a folder and point
NEURAL_ATLAS_TEST_SITE at it (see docs/addon.md). Without pytest args it runs tests/addon. The exit code
is pytest's; the process ends with os._exit so Blender 4.x cannot hang at exit (docs/blender-compat.md).
"""

from __future__ import annotations

import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main() -> int:
    args = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    site = os.environ.get("NEURAL_ATLAS_TEST_SITE")
    if site:
        sys.path.append(site)
    try:
        import pytest
    except ImportError:
        print(
            "blender_runner: pytest is not importable in Blender's Python. Install it with\n"
            '  <blender python> -m pip install --target ~/na-test-site pytest "OpenEXR==3.5.*"\n'
            "and run with NEURAL_ATLAS_TEST_SITE=~/na-test-site",
            file=sys.stderr,
        )
        return 2
    os.chdir(ROOT)
    sys.path.insert(0, ROOT)
    return int(pytest.main(["-q", "-p", "no:cacheprovider", *(args or ["tests/addon"])]))


if __name__ == "__main__":
    rc = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)
