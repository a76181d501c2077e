"""What ``contactid demo`` compiles ahead, in a process of its own, on the core its campaign leaves idle
(:func:`app.demo.compiling_ahead`): first the rig simulator's kernels besides its integration loop, whose calls
the campaign's loop, compiling meanwhile, loads from the disk cache as it reaches them
(:func:`drivers.simulation.kernels.compile_kernels`), and the emulated DAQ's converter; then the law library's
kernels for the analysis after the campaign (:mod:`analysis.prediction.compile_ahead`). Where the cache holds them
already, it only loads them."""
import os

from analysis.prediction.compile_ahead import compile_library
from drivers.emulator.daq import compile_converter
from drivers.simulation.kernels import compile_kernels


def main() -> None:
    os.nice(10)                 # the campaign and the analysis come first where they want the same core
    compile_kernels()
    compile_converter()
    compile_library()


if __name__ == "__main__":
    main()
