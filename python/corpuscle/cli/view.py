"""``corpuscle view RUN.cps``: serve a recorded run to a web page."""

from __future__ import annotations

import argparse
import importlib
import pathlib
import time
import warnings

from ._options import EXIT_OK, Command, UsageError, add_live_arguments, err, live_options, live_url_message, one_line, register


def _configure_view(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", metavar="RUN.cps", help="a recorded run")
    add_live_arguments(p)


def _cmd_view(args: argparse.Namespace) -> int:
    live_options(args, needs_live=False)
    path = pathlib.Path(args.run)
    if not path.is_file():
        raise UsageError(f"{path}: {'is a folder' if path.is_dir() else 'no such file'}")
    live = importlib.import_module("corpuscle.live")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a torn tail: its whole frames are shown
        try:
            server, run = live.serve_recording(path, host=args.host, port=args.port)
        except live.ServerError as exc:
            raise UsageError(f"view: {one_line(exc)}") from None
    err(live_url_message(server, f"viewing {path} ({len(run)} frames)"))
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        run.close()
    return EXIT_OK


register(Command("view", "serve a recorded run to a web page (play, pause, scrub, speed)", _configure_view,
                 _cmd_view))
