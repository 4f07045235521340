"""The ``sweepcast`` command: ``serve``, ``worker``, ``live`` (a rig's cameras to the service), ``openapi`` and one verb per engine."""
from __future__ import annotations

import argparse
import ipaddress
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path

ENGINE_CLIS = {
    "workers.orientation.cli": ("orient",),
    "workers.depth.cli": ("depth",),
    "workers.faces.cli": ("face",),
    "workers.sweep.cli": ("render",),
    "workers.drone.cli": ("reconstruct",),
    "app.keys_cli": ("keys",),
}
"""The modules that add the engine and key verbs (their ``register``), and the verbs each adds: a command line naming
one of them imports that module alone (the others' engines cost a second and a half of CPU to import: ``sweepcast
orient`` over a library starts that much sooner)."""


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        try:
            return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
        except (OSError, ValueError):
            return False


def _log_to_stderr(level: str) -> None:
    """The service's own log (``sweepcast.*``: Ray's start, the demo, jobs, kernels) on stderr beside uvicorn's, at
    ``level``; without a handler Python only prints its warnings. Called again, it replaces its handler."""
    logger = logging.getLogger("sweepcast")
    logger.handlers[:] = [h for h in logger.handlers if not getattr(h, "sweepcast_stderr", False)]
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    handler.sweepcast_stderr = True  # type: ignore[attr-defined]
    logger.addHandler(handler)
    logger.setLevel(level.upper())
    logger.propagate = False


def cmd_serve(args: argparse.Namespace) -> int:
    from app import raycluster
    from app.kernelcache import log_prebuilt
    from app.settings import Settings

    overrides = {k: v for k, v in {"host": args.host, "port": args.port, "data_dir": args.data_dir}.items() if v is not None}
    settings = Settings(**overrides)
    if not _is_loopback(settings.host) and not settings.api_keys and not args.insecure and not _managed_keys(settings):
        print(
            f"refusing to listen on {settings.host} without API keys: create one with 'sweepcast keys create --name "
            "NAME --role admin', set SWEEPCAST_API_KEYS=<key>[,<key>...], or pass --insecure to serve without "
            "authentication",
            file=sys.stderr,
        )
        return 2
    _log_to_stderr(args.log_level)
    log_prebuilt()
    raycluster.start_connecting(settings)  # Ray's start overlaps the imports below (readyz sooner)
    import uvicorn

    from app.http_protocol import http_protocol
    from app.main import create_app

    print(f"sweepcast: serving on http://{settings.host}:{settings.port} (data in {settings.data_dir.resolve()})",
          file=sys.stderr)
    # no permessage-deflate on the sockets: what they carry is JPEG (frames, live sets), which deflate cannot
    # shrink, so compressing it for every viewer only spent the API process's CPU
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level=args.log_level,
                ws_per_message_deflate=False, http=http_protocol(settings.header_timeout_seconds))
    return 0


def _managed_keys(settings: object) -> bool:
    """True when the service's database holds API keys (made with ``sweepcast keys create``)."""
    from app.keys_cli import opened_keys

    with opened_keys(settings) as keys:
        return keys.any()


def cmd_worker(args: argparse.Namespace) -> int:
    """Join this machine to a Ray cluster as a worker node (runs ``ray start --block`` until it ends)."""
    from app.netwait import split_address, wait_for_gcs
    from app.raycluster import HEAD_WAIT_S, ray_executable
    from app.raystart import start_node

    ray_bin = ray_executable()
    if ray_bin is None:
        print("the 'ray' command is not installed in this environment", file=sys.stderr)
        return 2

    try:
        split_address(args.address)
    except ValueError as exc:
        print(f"--address: {exc} (the Ray head, as printed by 'ray start --head')", file=sys.stderr)
        return 2
    argv = [ray_bin, "start", "--address", args.address, "--block"]
    if args.num_cpus is not None:
        argv += ["--num-cpus", str(args.num_cpus)]
    if args.num_gpus is not None:
        argv += ["--num-gpus", str(args.num_gpus)]
    if args.resources:
        try:
            json.loads(args.resources)
        except json.JSONDecodeError as exc:
            print(f"--resources must be a JSON object such as '{{\"renderer\": 1}}': {exc}", file=sys.stderr)
            return 2
        argv += ["--resources", args.resources]
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    from app.kernelcache import KernelWarmup, log_prebuilt
    from app.settings import Settings

    _log_to_stderr("info")
    log_prebuilt()
    if Settings().warm_kernels:  # this node's kernels, compiled while it joins
        KernelWarmup.start(Path(os.environ["NUMBA_CACHE_DIR"]), report=False)
    wait_for_gcs(args.address, HEAD_WAIT_S, ray_bin)  # ray start would wait ~40 s between its own tries
    return start_node(argv)  # started again if it stalls reaching the head (app/raystart.py)


def cmd_warmup(args: argparse.Namespace) -> int:
    """Compile the engines' kernels into the service's cache (``sweepcast warmup [ENGINE ...]``)."""
    from app.settings import Settings
    from workers import warmup

    settings = Settings(**({"data_dir": args.data_dir} if args.data_dir is not None else {}))
    # the demo's recording too (the viewer's first frame waits for it otherwise), unless the demo is off
    demo = settings.demo_rig and (not args.engines or "demo" in args.engines)
    print(f"sweepcast: compiling into {os.environ['NUMBA_CACHE_DIR']}", file=sys.stderr)
    return warmup.main([*args.engines, *(["--jobs", str(args.jobs)] if args.jobs is not None else []),
                        *(["--target", args.target] if args.target is not None else []),
                        *(["--demo-cache", str(settings.resolved_demo_cache_dir)] if demo else [])])


def cmd_wait_for(args: argparse.Namespace) -> int:
    """Wait until each ``host:port`` accepts a TCP connection (``--redis``: and answers PING, its data loaded;
    ``sweepcast wait-for``: the image's Ray head waits for its Redis): 0 when all did within the timeout, else 1."""
    from app.netwait import split_address, wait_for_port

    _log_to_stderr("info")
    try:
        for address in args.addresses:
            split_address(address)
    except ValueError as exc:
        print(f"sweepcast wait-for: {exc}", file=sys.stderr)
        return 2
    deadline = time.monotonic() + args.timeout
    reached: list[str] = []
    if not all(wait_for_port(a, max(deadline - time.monotonic(), 0.0), a, redis=args.redis, reached=reached)
               is not None for a in args.addresses):
        return 1
    if args.print_reached:
        print(" ".join(reached))
    return 0


def cmd_kernel_env(args: argparse.Namespace) -> int:
    """Print, as shell ``export`` lines, the environment that points numba at the service's kernel cache and, where
    the kernels compiled ahead are used, at their CPU target; ``eval "$(sweepcast kernel-env)"`` before any other
    process starts (the image's entrypoint) gives every Ray process of the container the same kernels."""
    import shlex

    from app.kernelcache import log_prebuilt

    _log_to_stderr("info")
    log_prebuilt()
    for name in ("NUMBA_CACHE_DIR", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES"):
        if name in os.environ:
            print(f"export {name}={shlex.quote(os.environ[name])}")
    return 0


def cmd_openapi(args: argparse.Namespace) -> int:
    from app.main import render_openapi

    text = render_openapi()
    if args.check:
        current = Path(args.out).read_text() if Path(args.out).exists() else ""
        if current != text:
            print(f"{args.out} is out of date: run 'sweepcast openapi'", file=sys.stderr)
            return 1
        return 0
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def cmd_models(args: argparse.Namespace) -> int:
    from workers.common.models import MODELS, ModelError, install, installed
    from app.settings import Settings

    data_dir = args.data_dir or Settings().data_dir
    if args.action == "list":
        for model in MODELS.values():
            path = installed(model, data_dir)
            print(f"{model.name:8} {'installed at ' + str(path) if path else 'not installed'}\n"
                  f"         {model.used_for}; licence {model.license}")
        return 0
    names = args.names or list(MODELS)
    unknown = [n for n in names if n not in MODELS]
    if unknown:
        print(f"unknown model {', '.join(unknown)}; known: {', '.join(MODELS)}", file=sys.stderr)
        return 2
    if args.source and len(names) != 1:
        print("--from needs exactly one model name", file=sys.stderr)
        return 2
    failed = 0
    for name in names:
        model = MODELS[name]
        if args.if_missing and installed(model, data_dir):
            continue
        try:
            path = install(model, data_dir, args.source, timeout=args.timeout)
        except ModelError as exc:
            print(f"not installed: {exc}", file=sys.stderr)
            failed += 1
            continue
        print(f"{name}: installed {path}", file=sys.stderr)
    return 1 if failed else 0


def build_parser(engines: bool = True, command: str | None = None) -> argparse.ArgumentParser:
    """Every verb; ``engines=False`` leaves out the keys and engine verbs, whose modules import the engines (a second
    of CPU: the service's own verbs, run at every container start, do without); with ``command`` one of those verbs
    (:data:`ENGINE_CLIS`), only its module's verbs are added."""
    parser = argparse.ArgumentParser(prog="sweepcast", description="sweepcast: the service and its engines from the command line.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("serve", help="run the HTTP/WebSocket service (local Ray, SQLite and a data folder by default)")
    p.add_argument("--host", help="address to listen on (default 127.0.0.1; SWEEPCAST_HOST)")
    p.add_argument("--port", type=int, help="port (default 8000; SWEEPCAST_PORT)")
    p.add_argument("--data-dir", type=Path, help="data folder (default ./sweepcast-data; SWEEPCAST_DATA_DIR)")
    p.add_argument("--insecure", action="store_true", help="allow a non-loopback host without API keys")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("worker", help="join this machine to a Ray cluster as a worker node")
    p.add_argument("--address", required=True, help="the Ray head, host:port (as printed by 'ray start --head')")
    p.add_argument("--num-cpus", type=int)
    p.add_argument("--num-gpus", type=int)
    p.add_argument("--resources", help="custom resources as JSON, e.g. '{\"renderer\": 1}'")
    p.set_defaults(func=cmd_worker)

    p = sub.add_parser("wait-for", help="wait until each HOST:PORT accepts TCP connections (exit 1 after --timeout)")
    p.add_argument("addresses", nargs="+", metavar="HOST:PORT")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds in all (default 120)")
    p.add_argument("--redis", action="store_true", help="each is a Redis: wait until it has loaded its data too")
    p.add_argument("--print-reached", action="store_true",
                   help="then print each as the IP:PORT reached (so what starts next need not look the name up)")
    p.set_defaults(func=cmd_wait_for)

    p = sub.add_parser("openapi", help="write (or --check) the committed OpenAPI document")
    p.add_argument("--out", default="openapi/openapi.json")
    p.add_argument("--check", action="store_true", help="exit 1 when the file differs from the app's schema")
    p.set_defaults(func=cmd_openapi)

    p = sub.add_parser("models", help="list or fetch the optional third-party models (checked by SHA-256)")
    p.add_argument("action", choices=["list", "fetch"])
    p.add_argument("names", nargs="*", help="models to fetch (default: all)")
    p.add_argument("--from", dest="source", help="install from this file or URL instead of the publisher's URL")
    p.add_argument("--data-dir", type=Path, help="data folder (default ./sweepcast-data; SWEEPCAST_DATA_DIR)")
    p.add_argument("--if-missing", action="store_true", help="skip models already installed")
    p.add_argument("--timeout", type=float, default=30.0, help="network timeout in seconds (default 30)")
    p.set_defaults(func=cmd_models)

    p = sub.add_parser("warmup", help="compile every engine's kernels into the kernel cache ahead of the first "
                                      "request (the service also does it at start-up), and render the demo's "
                                      "recording into the demo cache (with 'demo' or all engines, unless "
                                      "SWEEPCAST_DEMO_RIG=0)")
    p.add_argument("engines", nargs="*", help="sweep, demo, drone, dense, depth, faces (default: all)")
    p.add_argument("--jobs", type=int, help="processes compiling at once (default: one per core)")
    p.add_argument("--target", help="compile for this portable CPU baseline (x86-64-v3) instead of this CPU: a "
                                    "cache for other machines, e.g. SWEEPCAST_PREBUILT_KERNELS in an image")
    p.add_argument("--data-dir", type=Path, help="data folder whose settings apply (default ./sweepcast-data; "
                                                 "the kernels go to SWEEPCAST_NUMBA_CACHE_DIR, else NUMBA_CACHE_DIR, "
                                                 "else ~/.cache/sweepcast/kernels)")
    p.set_defaults(func=cmd_warmup)

    p = sub.add_parser("kernel-env", help="print the kernel cache's environment as shell exports (image entrypoint)")
    p.add_argument("--data-dir", type=Path, help="data folder whose settings apply (default ./sweepcast-data)")
    p.set_defaults(func=cmd_kernel_env)

    from app.capture.cli import register as register_live

    register_live(sub)

    if not engines:
        return parser
    import importlib

    named = [module for module, verbs in ENGINE_CLIS.items() if command in verbs]
    for module in named or ENGINE_CLIS:
        importlib.import_module(module).register(sub)
    return parser


SERVICE_COMMANDS = ("serve", "worker", "warmup", "kernel-env")
"""Commands that use the service's kernel cache (``Settings.resolved_numba_cache_dir``); the one-shot engine
commands keep numba's default (beside the sources, or ``NUMBA_CACHE_DIR``)."""
OWN_COMMANDS = (*SERVICE_COMMANDS, "openapi", "models", "wait-for", "live")
"""The verbs :func:`build_parser` defines itself (no engine imported to parse them)."""


def _command(argv: list[str]) -> str | None:
    """The verb of a ``sweepcast`` command line (the first argument that is not an option)."""
    return next((a for a in argv if not a.startswith("-")), None)


def _use_service_kernel_cache(argv: list[str], command: str | None) -> None:
    """Point numba at the service's cache before the parser imports the engines (and numba reads it)."""
    if command not in SERVICE_COMMANDS:
        return
    from app.kernelcache import use_cache_dir, use_prebuilt
    from app.settings import Settings

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--data-dir", type=Path)
    pre.add_argument("--target")
    known = pre.parse_known_args(argv)[0]
    settings = Settings(**({"data_dir": known.data_dir} if known.data_dir is not None else {}))
    cache = use_cache_dir(settings.resolved_numba_cache_dir)
    if command == "warmup" and known.target is not None:  # compile for a portable CPU target (before numba loads)
        from workers.portable_cache import TARGETS, target_env

        if known.target in TARGETS:  # (an unknown one: warmup's parser says so)
            os.environ.update(target_env(known.target))
    elif command != "warmup":  # kernels compiled ahead: their CPU target and a copy in the cache, before numba loads
        use_prebuilt(settings.resolved_prebuilt_kernels, cache)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command(argv)
    _use_service_kernel_cache(argv, command)
    args = build_parser(engines=command not in OWN_COMMANDS, command=command).parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
