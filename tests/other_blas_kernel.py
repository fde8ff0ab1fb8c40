"""Print an OpenBLAS kernel other than the one numpy picks on this machine, for running the suite a second time
(``OPENBLAS_CORETYPE=$(python tests/other_blas_kernel.py) python -m pytest``, issue 42): a test that pins the
round-off of one kernel then fails here, not on a user's machine. Prints nothing where no other kernel can run
(not x86-64, numpy not on OpenBLAS, or OPENBLAS_CORETYPE already set by the machine); ``--why`` says which.

Haswell (AVX2) where the default is another kernel and the CPU has AVX2, else Prescott (SSE3, any x86-64 CPU)."""

import os
import platform
import sys


def other_kernel() -> tuple[str, str]:
    if os.environ.get("OPENBLAS_CORETYPE"):
        return "", f"OPENBLAS_CORETYPE is already set ({os.environ['OPENBLAS_CORETYPE']}) on this machine"
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return "", f"the kernels named here are x86-64's; this machine is {platform.machine()}"
    import numpy  # noqa: F401 (loads its BLAS)
    from threadpoolctl import threadpool_info

    blas = [i for i in threadpool_info() if i.get("internal_api") == "openblas"]
    if not blas:
        return "", "numpy does not use OpenBLAS here"
    default = str(blas[0].get("architecture", ""))
    try:
        flags = open("/proc/cpuinfo").read()
    except OSError:
        flags = ""
    if default.lower() != "haswell" and " avx2" in flags:
        return "Haswell", ""
    return ("Prescott", "") if default.lower() != "prescott" else ("", "the default kernel is already Prescott")


if __name__ == "__main__":
    kernel, why = other_kernel()
    print(why if "--why" in sys.argv[1:] else kernel)
