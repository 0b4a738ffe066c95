"""The two-input two-output coupled-tank family (papers 000-002): transfer-function plants with
dead time (``model``), decouplers and the GPM / bandwidth designs (``design``), the jitted
simulators (``sim``, ``kernels``, ``two_tank``), the tuning problem, reports and the family's
config (``family``)."""
