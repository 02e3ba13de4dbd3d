"""``hingelab view PATH``: an episode file or a dataset folder in Rerun."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from hingelab.cli.options import add_on_corrupt
from hingelab.errors import ConfigError
from hingelab.out_dir import check_out_file


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "view",
        help="open an episode file or a dataset folder in Rerun (or save an .rrd)",
        description=(
            "Log an episode (tool cloud, tool frame, tips, object and target in hand_base; hand joints; "
            "latent z and z_goal; reward terms; success and attempt markers, on the simulated timeline) "
            "or a dataset (success per object and source, returns, lengths, all latents, every episode "
            "back to back on a 'dataset_step' timeline, and on 'episode' to step through them) to Rerun, laid "
            "out by the blueprints in viewers/. Without a "
            "display the recording is saved as ./NAME.rrd (open it later with `rerun NAME.rrd`)."
        ),
    )
    p.add_argument("path", type=Path, help="an episode file (.mcap) or a dataset folder")
    p.add_argument("--save", type=Path, default=None, metavar="FILE.rrd",
                   help="write the recording to this .rrd file instead of opening a viewer")
    p.add_argument("--web", action="store_true",
                   help="serve Rerun's web viewer (prints its address; Ctrl-C stops serving); only this "
                        "machine can open it unless --bind says otherwise")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="--web: the address to listen on (default 127.0.0.1, this machine only; 0.0.0.0 or a "
                        "network interface's address lets every machine that reaches it read the data)")
    p.add_argument("--port", type=int, default=9876, help="--web: the gRPC port (default 9876)")
    p.add_argument("--web-viewer-port", type=int, default=9090, help="--web: the web viewer's port (default 9090)")
    p.add_argument("--screenshot", type=Path, default=None, metavar="FILE.png",
                   help="serve the recording to Rerun's web viewer on this machine, open it in headless "
                        "Chromium (needs `chromium` on PATH, or HINGELAB_CHROMIUM=PATH) and save a 1600x1000 "
                        "PNG once the view has stopped changing; then stop serving")
    p.add_argument("--screenshot-timeout", type=float, default=240.0, metavar="S",
                   help="--screenshot: the longest wait for the view to settle, seconds (WebGL runs in "
                        "software; default 240)")
    p.add_argument("--cloud-every", type=int, default=10, metavar="K",
                   help="dataset view: keep every K-th tool cloud of each episode (1 = all; default 10)")
    p.add_argument("--max-episodes", type=int, default=None, metavar="N",
                   help="dataset view: only the first N episodes (default: all)")
    add_on_corrupt(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hingelab.viewers import view  # on run: the parser stays light (hingelab.cli)
    from hingelab.viewers.web_server import bind_warning

    if args.save is not None:
        check_out_file(args.save, "--save")
    if args.cloud_every < 1:
        raise ConfigError(f"--cloud-every must be at least 1, not {args.cloud_every}")

    if args.save is not None and args.web:
        raise ConfigError("give either --save FILE.rrd or --web, not both")
    if args.screenshot is not None:
        return _screenshot(args, view)
    if args.web:
        warning = bind_warning(args.bind, args.port, args.web_viewer_port)
        if warning:
            print(warning, file=sys.stderr)
    result, rec = view(args.path, save=args.save, web=args.web, cloud_every=args.cloud_every,
                       max_episodes=args.max_episodes, bind=args.bind, port=args.port,
                       web_port=args.web_viewer_port)
    what = (f"{result.episodes} episode{'s' if result.episodes != 1 else ''} "
            f"({result.steps} steps) of {result.kind} {result.name!r}")
    if result.saved_to is not None:
        print(f"Logged {what} in {result.seconds:.2f} s and saved the recording to {result.saved_to}; "
              f"open it with `rerun {result.saved_to}` (the layout is inside; viewers/ keeps it as .rbl).")
    elif result.server is not None:
        print(f"Logged {what} in {result.seconds:.2f} s; Rerun's web viewer is serving it at {result.url} "
              "(Ctrl-C stops).", flush=True)

        def stop_on_signal(signum, frame):
            raise KeyboardInterrupt  # a kill or a closed terminal stops the server too, not only Ctrl-C

        signal.signal(signal.SIGTERM, stop_on_signal)
        signal.signal(signal.SIGHUP, stop_on_signal)
        try:
            result.server.wait()
        except KeyboardInterrupt:
            pass
        finally:
            result.server.stop()
    else:
        print(f"Logged {what} in {result.seconds:.2f} s to a spawned Rerun viewer.")
    return 0


def _screenshot(args: argparse.Namespace, view) -> int:
    from hingelab.viewers.screenshot import capture_page, chromium_executable
    from hingelab.viewers.web_server import LOOPBACK, free_port

    if args.save is not None or args.web:
        raise ConfigError("--screenshot serves the recording itself: leave out --save and --web")
    if args.screenshot.suffix.lower() != ".png":
        raise ConfigError(f"--screenshot {args.screenshot}: the file must end in .png")
    if not args.screenshot_timeout > 0:
        raise ConfigError(f"--screenshot-timeout must be a positive number of seconds, not {args.screenshot_timeout}")
    check_out_file(args.screenshot, "--screenshot")
    chromium_executable()  # before logging: no Chromium is one line, not a wasted recording
    result, _ = view(args.path, web=True, cloud_every=args.cloud_every, max_episodes=args.max_episodes,
                     bind=LOOPBACK, port=free_port(), web_port=free_port())
    try:
        shot = capture_page(result.url, args.screenshot, timeout_s=args.screenshot_timeout)
    finally:
        result.server.stop()
    what = (f"{result.episodes} episode{'s' if result.episodes != 1 else ''} "
            f"({result.steps} steps) of {result.kind} {result.name!r}")
    print(f"Logged {what}; Rerun's web viewer drawn in headless Chromium and saved to {args.screenshot} "
          f"({shot['bytes'] / 1024:.0f} KiB, {shot['seconds']:.0f} s, {shot['captures']} captures).")
    if not shot["settled"]:
        print(f"warning: the view was still changing after {args.screenshot_timeout:.0f} s; the file holds the "
              "last capture (raise --screenshot-timeout on a busy machine)", file=sys.stderr)
    return 0
