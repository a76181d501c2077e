"""Writes a session line by line until killed (used by tests/test_session.py): prints the writer process's pid,
then the index of every line once append_line has returned."""
import sys

import numpy as np

from app.session.writer import RunSpec, SessionWriter

path = sys.argv[1]
w = SessionWriter(path, plan_text="[[stepped_sine]]\nforce = 0.8\n", software_version="test")
w.begin_run(RunSpec("sine_0.8N_up", "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0,
                    ["force", "acc:x1", "acc:x2"], ["N", "m/s^2", "m/s^2"],
                    extras={"force_amplitude": ("N", (), "f8")}))
print(w.writer_pid, flush=True)
i = 0
while True:
    f = 1.0 + 0.01 * i
    w.append_line(f, {"x1": complex(i, 1), "x2": complex(i, 2)}, {"force_amplitude": 0.8},
                  raw=np.full((500, 3), i, dtype=np.float32))
    print(i, flush=True)
    i += 1
