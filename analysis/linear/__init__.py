"""The reference linear model: modal reference from a random run (``reference``) or from the lowest stepped-sine
level (``level_reference``), and its updating to measured natural frequencies (``updating``).

May import: ``common``, ``mechanics``, ``signals``.
"""
