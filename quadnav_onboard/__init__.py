"""quadnav-onboard: end-to-end DQN motion planning for quadrotors, flown through PX4.

The pure core shared by training and flight: :mod:`frames`, :mod:`path`, :mod:`primitives`,
:mod:`reward`, :mod:`network`, :mod:`checkpoint`, :mod:`preprocess`, :mod:`config`.
"""

__version__ = "0.1.0"
