"""The old name of :mod:`icenav.apps.wiring`, kept for scripts and checks that import it.

``icenav.app.make_sim_controller`` is :func:`icenav.apps.wiring.make_sim_controller`.
"""

from icenav.apps.wiring import SimSession, make_sim_controller

__all__ = ["SimSession", "make_sim_controller"]
