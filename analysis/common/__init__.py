"""What every room shares: errors that name the field (``errors``), TOML tables (``tables``), the measurement
records the app hands in (``measurements``), the statistics every judgement uses -- the noise weight of a kbar,
the parameter-charging criterion, the outlier limit, the noise bound (``statistics``) -- and numbers in the words
a user reads (``wording``).

May import: numpy and scipy only: no other room.
"""
