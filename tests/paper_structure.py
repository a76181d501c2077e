"""The paper's 2-DOF structure (M = diag(1, 2) kg, K = 100 [[2, -1], [-1, 2]] N/m) as the ``[structure]`` table
of a model or rig file: tests append their elements to it."""
PAPER_STRUCTURE = """[structure]
type = "lumped"
dofs = ["x1", "x2"]
mass = [[1.0, 0.0], [0.0, 2.0]]
stiffness = [[200.0, -100.0], [-100.0, 200.0]]
"""
