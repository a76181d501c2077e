"""The rig simulation: rig files, the linear model and its reduction, the exact discretisation, generator and
sensor models, the numba integration kernels and the built-in rigs.

It depends on :mod:`analysis` only (laws <- simulation <- emulator <- app): the emulator in
:mod:`drivers.emulator` never imports it and is handed a :class:`~drivers.simulation.simulator.RigSimulator`
as its physics backend by the app (:mod:`app.campaign.instruments`).
"""
