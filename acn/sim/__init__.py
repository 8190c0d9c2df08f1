"""The simulators and what they simulate: the A1, its state, backends, effects, policies, re-simulation.

MuJoCo's own log is turned off here, for every process that simulates: a warning (a huge control,
an unstable step) would be printed and written to ``MUJOCO_LOG.TXT`` in the user's working
directory. The toolkit reads the warnings it acts on from ``MjData.warning`` and refuses values no
A1 can produce before they reach a simulator (``acn.sim.plausible``).
"""

import mujoco as _mujoco

_quiet = _mujoco.MjLogConfig()
_quiet.logto_console, _quiet.logto_file = False, False
_quiet.set()
