"""Entry point of a render worker process (see `frames.FramePool`)."""

import sys

from worker.simulator.frames import serve

if __name__ == "__main__":
    serve(sys.stdin.buffer, sys.stdout.buffer)
