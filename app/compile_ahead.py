"""What ``contactid demo`` compiles ahead, in a process of its own, on the core its campaign leaves idle
(:func:`app.demo.compiling_ahead`): first the rig's integration loop's calls of their own, which the campaign's
loop, compiling meanwhile, loads from the disk cache as it reaches them
(:func:`drivers.simulation.kernels.compile_callees`); then the law library's kernels for the analysis after the
campaign (:mod:`analysis.prediction.compile_ahead`). Where the cache holds them already, it only loads them."""
from analysis.prediction.compile_ahead import compile_library
from drivers.simulation.kernels import compile_callees


def main() -> None:
    compile_callees()
    compile_library()


if __name__ == "__main__":
    main()
