"""The 2 GB ceiling of a 24-megapixel `relight image` run and the child process that measures its
peak RSS (tests/relight/network/test_runtime_memory.py, tests/relight/person/test_matte.py)."""

LIMIT_BYTES = 2 * 1024 ** 3
CHILD = r"""
import resource, sys
from relight.cli import main
code = main(sys.argv[1:])
# VmHWM is this process image's own peak; ru_maxrss would also count the
# parent's RSS at fork time (Linux keeps it across exec)
try:
    kib = int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1])
except (OSError, StopIteration):
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print("PEAK_RSS_BYTES", kib * 1024)
sys.exit(code)
"""
