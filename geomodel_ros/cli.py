"""``python -m geomodel_ros.cli``: the ``geomodel`` command (see :mod:`geomodel_ros.tools.cli`)."""

import sys

from geomodel_ros.tools.cli import main

if __name__ == "__main__":
    sys.exit(main())
