"""The contract between the engine and the Blender add-on. Standard library only.

The add-on may import this module and nothing else of ``engine``: CLI verbs and exit codes, the run
folder's file names, the JSON progress lines the engine prints, and the requirements (with their exact versions) the
add-on's "Set up engine" installs. Anything that crosses the process boundary is named here, once: the requirements
below, and every name of the contract's terms (engine/terms/, one module per subject, standard library only too),
each reached as ``contract.NAME``.
"""

from __future__ import annotations

from pathlib import Path

from .terms.cli import *  # noqa: F403
from .terms.clip import *  # noqa: F403
from .terms.colour import *  # noqa: F403
from .terms.export_names import *  # noqa: F403
from .terms.farm import *  # noqa: F403
from .terms.lock import *  # noqa: F403
from .terms.manifest import *  # noqa: F403
from .terms.paths import *  # noqa: F403
from .terms.protocol import *  # noqa: F403
from .terms.run_folder import *  # noqa: F403
from .terms.versions import *  # noqa: F403

#: The requirement files beside this module (shipped in the wheel and the extension), each read once here. Ranges:
#: the engine's and the farm extra's (pyproject.toml takes its dependencies from the same two files). Exact versions:
#: the constraints file every install here uses (``pip install -r ... -c constraints.txt``).
REQUIREMENTS_FILE = "requirements.txt"
FARM_REQUIREMENTS_FILE = "requirements-farm.txt"
CONSTRAINTS_FILE = "constraints.txt"
CONSTRAINTS_PATH = Path(__file__).with_name(CONSTRAINTS_FILE)


def requirement_lines(name: str) -> tuple[str, ...]:
    """The requirements of one of the files beside this module: its lines less blanks and ``#`` comments (the rule
    setuptools applies to the same files)."""
    text = Path(__file__).with_name(name).read_text(encoding="utf-8")
    return tuple(s for s in (line.strip() for line in text.splitlines()) if s and not s.startswith("#"))


#: The engine's requirements (compatible ranges), which the add-on's Set up engine installs with the constraints.
ENGINE_REQUIREMENTS: tuple[str, ...] = requirement_lines(REQUIREMENTS_FILE)
#: The farm back ends' own requirements (the wheel's ``farm`` extra; the test venv has them).
FARM_REQUIREMENTS: tuple[str, ...] = requirement_lines(FARM_REQUIREMENTS_FILE)
