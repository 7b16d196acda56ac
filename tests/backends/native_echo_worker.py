"""A native worker for the protocol's tests (``backends.native_worker.serve``): ``pid`` says which process
answered, ``echo`` returns its argument, ``fail`` raises."""

import os

from simseam.backends.native_worker import serve


def _fail(why: str) -> None:
    raise ValueError(why)


if __name__ == "__main__":
    serve({"pid": os.getpid, "echo": lambda value: value, "fail": _fail})
