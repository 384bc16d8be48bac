"""Count the hops a photo takes through the core package while `relight image` relights it.

    python tools/trace_hops.py [PHOTO] [--light sunset] [--quality best] [--list] [--from run_image]

Runs `relight image PHOTO --light LIGHT --quality QUALITY --out TMP.png` in this process
(relight.cli.main) under sys.setprofile / threading.setprofile and reports, for the calls
into the project's own code (files under the `relight` package folder, wherever they sit in
its subpackages; not the standard library, not third-party code):

- **function hops**: the distinct caller -> callee edges between project functions, where
  the caller is the nearest project function on the callee's stack (calls through the
  standard library or numpy, a thread pool's worker for instance, count as one hop from the
  project function that handed the work over; a thread's first project function has no
  caller and is no hop). Distinct edges, not every call: a loop over tiles, rows or frames
  counts once, so the number does not depend on the photo's size or the core count.
  Generator expressions, lambdas and comprehensions (`<genexpr>`, `<lambda>`, ...) are
  transparent (their calls belong to the function around them), and code run while a
  project module is imported (`<module>`) is not followed.
- **module returns**: walking the hop list of each thread in the order its edges were
  first taken, the sequence of project modules entered (the thread's first module, then
  the callee's module of each hop that crosses into another module); each entry into a
  module that is already in that sequence is one return to a module already left. An
  edge seen first in an earlier thread (threads taken main thread first, then by name)
  is not counted again.

`--from FUNCTION` also counts both within one call: the hops first taken, on any thread, while
the first project function whose qualified name is FUNCTION (`run_image`: `relight image` from
its parsed arguments on) runs on the main thread, and their returns, the main thread's sequence
starting at FUNCTION's module (a module left and entered again within the call is a return;
what the parser's construction entered before is not).

The counts are a fresh process's: run again in one process, the command skips what its
first run cached (onnxruntime sessions, tables) and takes fewer hops.

Modules are named by their file, relative to the folder that holds the `relight` package
(`relight/files/photo.py`, or `relight/io/photo.py` after a move), so the tool counts the same
way after modules move into subpackages. The raw counts (every call, every module change
of the call sequence) are printed too, for information: they depend on the photo's size;
`--calls validate_coeffs` counts every call of the matching functions (how often a check ran).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import relight  # noqa: E402  (after the path above)

PACKAGE = Path(relight.__file__).resolve().parent
BASE = PACKAGE.parent
DEFAULT_PHOTO = PACKAGE / "data" / "examples" / "grace_hopper.jpg"


class Tracer:
    """The profile function of every thread: per thread, its distinct edges in first-seen order."""

    def __init__(self, scope: str | None = None):
        self.lock = threading.Lock()
        self.edges: dict[str, list[tuple[str, str]]] = {}  # thread name -> distinct edges in order
        self.seen: dict[str, set] = {}
        self.roots: dict[str, list[str]] = {}  # thread name -> functions entered with no project caller
        self.scope = scope  # a function's qualified name: the edges first taken while its call runs, too
        self.scope_frame = None  # that call's frame while it runs on the main thread
        self.scope_function: str | None = None  # 'module:qualname' of the scope's call
        self.scoped = Tracer() if scope is not None else None  # the edges and roots within the call
        self.calls = 0  # every call into a project function (raw)
        self.module_changes = 0  # every call that changes the innermost project module (raw)
        self.raw_returns = Counter()  # raw: calls into a module entered before in the same thread
        self.called = Counter()  # raw: calls per project function ('module:qualname')
        self.entered: dict[str, set] = {}
        self.files: dict[str, str | None] = {}

    def module(self, filename: str) -> str | None:
        """The project module of a code file, relative to BASE; None outside the package."""
        known = self.files.get(filename)
        if known is not None or filename in self.files:
            return known
        try:
            path = Path(filename).resolve()
            name = path.relative_to(BASE).as_posix() if path.is_relative_to(PACKAGE) else None
        except (OSError, ValueError):
            name = None
        self.files[filename] = name
        return name

    def project_function(self, frame):
        """(module, 'module:qualname') of the nearest project function at or above `frame`,
        skipping transparent frames; (None, None) when none; ('<module>', None) when a
        project module's import is under way anywhere above."""
        found = None, None
        while frame is not None:
            module = self.module(frame.f_code.co_filename)
            if module is not None:
                name = frame.f_code.co_name
                if name == "<module>":
                    return "<module>", None  # anywhere above: import-time code
                if found[0] is None and not name.startswith("<"):
                    found = module, f"{module}:{frame.f_code.co_qualname}"
            frame = frame.f_back
        return found

    def __call__(self, frame, event, arg):
        if event == "return" and frame is self.scope_frame:
            self.scope_frame = None  # the scope's call returned: nothing after it is within
            return
        if event != "call":
            return
        module = self.module(frame.f_code.co_filename)
        if module is None or frame.f_code.co_name.startswith("<"):
            return
        caller_module, caller = self.project_function(frame.f_back)
        if caller_module == "<module>":
            return  # import-time code
        callee = f"{module}:{frame.f_code.co_qualname}"
        thread = threading.current_thread().name
        if self.scoped is not None:
            if (self.scope_frame is None and self.scope_function is None and thread == "MainThread"
                    and frame.f_code.co_qualname == self.scope):
                self.scope_frame, self.scope_function = frame, callee  # the first such call only
            elif self.scope_frame is not None:
                self.scoped.record(thread, module, caller_module, caller, callee)
        self.record(thread, module, caller_module, caller, callee)

    def record(self, thread: str, module: str, caller_module: str | None, caller: str | None, callee: str) -> None:
        """One call into project function `callee` (of `module`) by `caller` (None: no project caller)."""
        with self.lock:
            self.calls += 1
            self.called[callee] += 1
            entered = self.entered.setdefault(thread, set())
            if module != caller_module:
                self.module_changes += 1
                if module in entered:
                    self.raw_returns[module] += 1
                entered.add(module)
            if caller is None:
                self.roots.setdefault(thread, [])
                if callee not in self.roots[thread]:
                    self.roots[thread].append(callee)
                return
            seen = self.seen.setdefault(thread, set())
            if (caller, callee) not in seen:
                seen.add((caller, callee))
                self.edges.setdefault(thread, []).append((caller, callee))


def _threads_in_order(names):
    return sorted(names, key=lambda n: (n != "MainThread", n))


def count(tracer: Tracer, start: str | None = None):
    """(hop list [(thread, caller, callee, returns_to_module or None)], returns per module); `start`:
    the main thread's first module ('module:qualname' of the function it starts in), when its edges
    have no root of their own (a scope's)."""
    hops, returns, done = [], Counter(), set()
    for thread in _threads_in_order(set(tracer.edges) | set(tracer.roots)):
        first = tracer.roots.get(thread, [])[:1] or ([start] if start and thread == "MainThread" else [])
        sequence = [f.split(":")[0] for f in first]
        for caller, callee in tracer.edges.get(thread, []):
            if (caller, callee) in done:
                continue
            done.add((caller, callee))
            into = callee.split(":")[0]
            back = None
            if into != caller.split(":")[0]:
                if into in sequence:
                    back = into
                    returns[into] += 1
                sequence.append(into)
            hops.append((thread, caller, callee, back))
    return hops, returns


def by_caller(hops) -> str:
    """The hop list one line per caller, callers in the order first seen, `relight/` and `.py`
    left out: `cli_image.run_image -> cli_image.ImageRequest.from_args, cli_output.check_not_an_input`."""
    def short(function: str) -> str:
        module, name = function.split(":", 1)
        return module.removeprefix("relight/").removesuffix(".py").replace("/", ".") + "." + name

    lines: dict[tuple[str, str], list[str]] = {}
    for thread, caller, callee, back in hops:
        lines.setdefault((short(caller), thread), []).append(short(callee) + ("*" if back else ""))
    return "\n".join(f"{caller}{'' if thread == 'MainThread' else f' [{thread}]'} -> {', '.join(callees)}"
                     for (caller, thread), callees in lines.items())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("photo", nargs="?", default=str(DEFAULT_PHOTO))
    parser.add_argument("--light", default="sunset")
    parser.add_argument("--quality", default="best")
    parser.add_argument("--list", action="store_true", help="print the hop list")
    parser.add_argument("--by-caller", action="store_true",
                        help="print the hop list one line per caller (as docs/ARCHITECTURE.md shows it): "
                             "module.function [thread] -> its callees, * on a return to a module already left")
    parser.add_argument("--from", dest="scope", metavar="FUNCTION", default=None,
                        help="also count the hops and returns within the first call of FUNCTION (a qualified "
                             "name: run_image) on the main thread, the returns from FUNCTION's module on")
    parser.add_argument("--calls", action="append", default=[], metavar="TEXT",
                        help="also print how often each project function whose 'module:qualname' contains "
                             "TEXT was called (every call, any caller: how often a check ran); repeatable")
    args = parser.parse_args(argv)

    from relight import cli

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "relit.png"
        command = ["image", args.photo, "--light", args.light, "--quality", args.quality, "--out", str(out)]
        tracer = Tracer(args.scope)
        threading.setprofile(tracer)
        sys.setprofile(tracer)
        try:
            rc = cli.main(command)
        finally:
            sys.setprofile(None)
            threading.setprofile(None)
    if rc != 0:
        print(f"trace_hops: relight {' '.join(command)} exited {rc}", file=sys.stderr)
        return rc

    hops, returns = count(tracer)
    modules = sorted({c.split(":")[0] for _, a, b, _ in hops for c in (a, b)}
                     | {r.split(":")[0] for roots in tracer.roots.values() for r in roots})
    if args.list:
        for i, (thread, caller, callee, back) in enumerate(hops, 1):
            mark = f"  <- back to {back}" if back else ""
            where = "" if thread == "MainThread" else f" [{thread}]"
            print(f"{i:4d} {caller} -> {callee}{where}{mark}")
        print()
    if args.by_caller:
        print(by_caller(hops))
        print()
    print(f"command: relight {' '.join(command[:-1])} TMP.png")
    print(f"{'project modules entered':40s} {len(modules):6d}")
    print(f"{'function hops (distinct edges)':40s} {len(hops):6d}")
    print(f"{'returns to a module already left':40s} {sum(returns.values()):6d}")
    for module, n in returns.most_common():
        print(f"    {module:36s} {n:6d}")
    print(f"{'raw: calls into project functions':40s} {tracer.calls:6d}")
    print(f"{'raw: module changes':40s} {tracer.module_changes:6d}")
    print(f"{'raw: returns to a module entered before':40s} {sum(tracer.raw_returns.values()):6d}")
    if tracer.scoped is not None:
        if tracer.scope_function is None:
            print(f"trace_hops: --from {args.scope}: no such function was called", file=sys.stderr)
            return 1
        scoped, scoped_returns = count(tracer.scoped, tracer.scope_function)
        if args.by_caller:
            print(f"within {tracer.scope_function}:")
            print(by_caller(scoped))
        print(f"{'within ' + args.scope + ': function hops':40s} {len(scoped):6d}")
        print(f"{'within ' + args.scope + ': returns':40s} {sum(scoped_returns.values()):6d}")
        for module, n in scoped_returns.most_common():
            print(f"    {module:36s} {n:6d}")
    for text in args.calls:
        for function, n in sorted(tracer.called.items()):
            if text in function:
                print(f"    calls of {function:52s} {n:6d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
