"""On top: the workbench that carries one model through identification, fitting, prediction and diagnosis
(``workbench``), and the loop that follows the advice by itself (``auto``).

May import: every room.
"""
