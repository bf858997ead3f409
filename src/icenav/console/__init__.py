"""The operator console in the browser (viser): 3-D scene, live ICE image, controls, status.

:class:`Console` serves it for any :class:`icenav.control.state.ControllerCommands`;
:mod:`icenav.console.scene` and :mod:`icenav.console.panels` hold its pure logic.
"""

from icenav.console.app import Console, ConsoleStats
from icenav.console.freshness import ConsoleConfig
from icenav.console.scene import MM_TO_SCENE, AnatomyMesh

__all__ = ["AnatomyMesh", "Console", "ConsoleConfig", "ConsoleStats", "MM_TO_SCENE"]
