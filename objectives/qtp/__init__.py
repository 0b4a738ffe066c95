"""The quadruple-tank process family: model (``model``, ``bond_graph``), controllers (FOLQI,
IOLQI, LQI, LADR with the Oustaloup approximation), the jitted closed loop (``kernels``,
``loop``), the tuning problem, margins, the family's config (``family``) and the thesis'
chapter tables (``thesis``)."""
