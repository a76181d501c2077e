import os

# GUI tests run without a display.
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# The tests' matrices are small and the suite runs beside emulator and writer processes on two cores:
# threaded BLAS there spends more time waiting than computing (a 1000 x 201 SVD, 5.5 s against 0.4 s).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
