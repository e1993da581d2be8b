"""The browse page's server: a small Starlette (ASGI) app served by uvicorn, and ``d5rl browse``.

Starlette + uvicorn rather than a dashboard framework: the page is a handful of JSON endpoints and
one static page, Starlette is a few thousand lines with two dependencies, and the endpoints stay
plain functions that tests call through its TestClient.  Plots are drawn in the browser by Plotly.js,
whose bundle ships inside the ``plotly`` wheel and is served from here: the page loads nothing from
the internet.

Every file the page can read is named by a task id (looked up in the registry), an episode index,
a camera the episode has, a run number (an index into the directories given on the command line)
or a path relative to a run directory, and is resolved and checked to lie inside ``$D5RL_HOME`` or
that run directory (:mod:`d5rl.browse.safe`).  Endpoints only read, except for the frame strips
cached under ``$D5RL_HOME/browse-cache``.

Requests must name this server in their ``Host`` header: ``localhost``, a loopback or other IP address,
the ``--host`` it listens on, or this machine's host name.  A web page on another site can point a name
of its own at 127.0.0.1 (DNS rebinding) and then read this server as that name from the user's browser;
such a request carries the attacker's name and gets 400.  An IP address cannot be rebound.
"""

from __future__ import annotations

import contextlib
import ipaddress
import socket
import sys
from pathlib import Path

from d5rl.errors import D5RLError, is_int
from d5rl.registry import get_spec

STATIC = Path(__file__).resolve().parent / "static"
VIDEO_TYPES = {".mp4": "video/mp4", ".webm": "video/webm", ".gif": "image/gif"}
DEFAULT_PORT = 8765


def plotly_js() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("plotly")
    path = Path(spec.origin).parent / "package_data" / "plotly.min.js" if spec and spec.origin else None
    if path is None or not path.is_file():
        raise D5RLError("the plotly package (its bundled plotly.min.js) is missing", "pip install 'd5rl[browse]'")
    return path


LOCAL_NAMES = ("localhost", "127.0.0.1", "::1")


def host_names(host: str | None = None) -> frozenset[str]:
    """The names a request's ``Host`` may give for a server listening on ``host`` (IP addresses pass anyway)."""
    names = {*LOCAL_NAMES, socket.gethostname(), socket.getfqdn(), *([host] if host else [])}
    return frozenset(n.lower().rstrip(".") for n in names if n)


def host_allowed(header: str, names: frozenset[str]) -> bool:
    """Whether a ``Host`` header (``name``, ``name:port``, ``[v6]:port``) names this server."""
    h = header.strip().lower()
    if h.startswith("["):
        h = h[1 : h.find("]")] if "]" in h else ""
    elif h.count(":") == 1:
        h = h.split(":")[0]
    h = h.rstrip(".")
    if not h:
        return False
    if h in names:
        return True
    try:
        ipaddress.ip_address(h)
    except ValueError:
        return False
    return True


class HostCheck:
    """ASGI middleware: 400 for a request whose ``Host`` is not a name of this server (see the module docstring)."""

    def __init__(self, app, names: frozenset[str]):
        self.app, self.names = app, names

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket"):
            host = dict(scope["headers"]).get(b"host", b"").decode("latin-1")
            if not host_allowed(host, self.names):
                from starlette.responses import PlainTextResponse

                msg = (
                    f"Host {host!r} is not a name of this d5rl browse server; open it as http://localhost:PORT/ "
                    "or start it with --host NAME"
                )
                await PlainTextResponse(msg, status_code=400)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def create_app(run_dirs: list[Path] | None = None, host: str | None = None):
    """The ASGI app over the tasks in the registry, ``$D5RL_HOME`` and the given run directories, answering
    requests addressed to ``host`` (see :func:`host_names`)."""
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.responses import FileResponse, JSONResponse, PlainTextResponse
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    # start-up time: d5rl's CLI imports this module for its parser; the app's pages load only to serve
    from d5rl.browse import catalog, runs
    from d5rl.browse.frames import Frames, NoFrames
    from d5rl.browse.safe import NotAllowed, file_under
    from d5rl.errors import DatasetNotFoundError, TaskIdError, UnknownTaskError

    run_dirs = [Path(r).resolve() for r in (run_dirs or [])]
    run_labels = runs.run_labels(run_dirs)
    datasets = catalog.Datasets()
    frames = Frames(datasets)
    plotly = plotly_js()

    def guarded(fn):
        def endpoint(request):
            try:
                return fn(request)
            except NotAllowed as e:
                return JSONResponse({"error": e.message}, status_code=403)
            except (UnknownTaskError, TaskIdError, DatasetNotFoundError, NoFrames, IndexError, KeyError) as e:
                msg = getattr(e, "message", None) or (e.args[0] if e.args else str(e))
                hint = getattr(e, "hint", None)
                return JSONResponse({"error": str(msg), "hint": hint}, status_code=404)
            except (D5RLError, ValueError) as e:
                return JSONResponse(
                    {"error": getattr(e, "message", str(e)), "hint": getattr(e, "hint", None)}, status_code=400
                )

        endpoint.__name__ = fn.__name__
        return endpoint

    def index_of(request, name: str = "index") -> int:
        raw = request.path_params[name]
        if not raw.isdigit() or len(raw) > 9:
            raise ValueError(f"{raw!r} is not an index")
        return int(raw)

    def run_dir(request) -> Path:
        k = index_of(request, "run")
        if k >= len(run_dirs):
            raise KeyError(f"no run {k}: {len(run_dirs)} run directories were given to `d5rl browse`")
        return run_dirs[k]

    def task_id(request) -> str:
        return get_spec(request.path_params["task"]).id  # only registered ids go further

    def page(request):
        return FileResponse(STATIC / "index.html")

    def tasks(request):
        return JSONResponse(
            {
                "tasks": catalog.all_tasks(),
                "runs": [
                    {"index": k, "name": r.name, "label": run_labels[k], "path": str(r)} for k, r in enumerate(run_dirs)
                ],
            }
        )

    def task(request):
        return JSONResponse(catalog.task_summary(task_id(request)))

    def overview(request):
        t = task_id(request)
        return JSONResponse(catalog.overview(t, datasets.get(t)))

    def episodes(request):
        t = task_id(request)
        return JSONResponse(catalog.episodes_table(t, datasets.get(t)))

    def episode(request):
        t = task_id(request)
        return JSONResponse(catalog.episode_series(t, datasets.get(t), index_of(request)))

    def episode_frames(request):
        return JSONResponse(frames.episode_frames(task_id(request), index_of(request)))

    def frame_strip(request):
        path = frames.strip_path(task_id(request), index_of(request), request.path_params["camera"])
        return FileResponse(
            path,
            media_type="image/png" if path.suffix == ".png" else "image/jpeg",
            headers={"Cache-Control": "no-cache"},
        )

    def datacard(request):
        path = file_under(catalog.DOCS, request.path_params["name"], (".md",))
        return PlainTextResponse(path.read_text())

    def run(request):
        d = run_dir(request)
        k = index_of(request, "run")
        return JSONResponse({"index": k, "label": run_labels[k], **runs.run_summary(d)})

    def run_file(request):
        path = file_under(run_dir(request), request.path_params["path"], tuple(VIDEO_TYPES))
        return FileResponse(path, media_type=VIDEO_TYPES[path.suffix.lower()])

    def plotly_bundle(request):
        return FileResponse(plotly, media_type="text/javascript", headers={"Cache-Control": "max-age=86400"})

    routes = [
        Route("/", page),
        Route("/api/tasks", guarded(tasks)),
        Route("/api/tasks/{task}", guarded(task)),
        Route("/api/tasks/{task}/overview", guarded(overview)),
        Route("/api/tasks/{task}/episodes", guarded(episodes)),
        Route("/api/tasks/{task}/episodes/{index}", guarded(episode)),
        Route("/api/tasks/{task}/episodes/{index}/frames", guarded(episode_frames)),
        Route("/api/tasks/{task}/episodes/{index}/frames/{camera}", guarded(frame_strip)),
        Route("/api/datacards/{name}", guarded(datacard)),
        Route("/api/runs/{run}", guarded(run)),
        Route("/api/runs/{run}/files/{path:path}", guarded(run_file)),
        Route("/vendor/plotly.min.js", plotly_bundle),
        Mount("/static", app=StaticFiles(directory=STATIC), name="static"),
    ]

    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        frames.close()

    app = Starlette(routes=routes, lifespan=lifespan, middleware=[Middleware(HostCheck, names=host_names(host))])
    app.state.frames = frames
    return app


def serve(host: str, port: int, run_dirs: list[Path]) -> None:
    try:
        import uvicorn
    except ModuleNotFoundError:
        raise D5RLError(
            "`d5rl browse` needs the browse extra (starlette, uvicorn, plotly)",
            "pip install 'd5rl[browse]' (from a checkout: bash -c 'source scripts/install.sh train,browse')",
        ) from None
    for r in run_dirs:
        if not Path(r).is_dir():
            raise D5RLError(f"run directory {r} does not exist", "pass the --out directory of `d5rl bench`")
    if not is_int(port, lo=1, hi=65535):
        raise D5RLError(f"--port must be from 1 to 65535, got {port!r}", "omit --port for 8765")
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        try:
            s.bind((host, port))
        except socket.gaierror as e:  # not an address or a name of this machine
            raise D5RLError(
                f"cannot listen on {host}: {e.strerror}",
                "pass an address of this machine with --host (omit it for 127.0.0.1)",
            ) from None
        except OSError as e:
            raise D5RLError(f"cannot listen on {host}:{port}: {e.strerror}", "pick another port with --port") from None
    app = create_app(run_dirs, host)
    if host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"warning: listening on {host}: anyone who can reach this machine can read your datasets and runs",
            file=sys.stderr,
        )
    print(f"d5rl browse: http://{'[' + host + ']' if ':' in host else host}:{port}/  (Ctrl-C stops)", flush=True)
    uvicorn.run(app, host=host, port=port, log_level="warning")


def cmd_browse(args) -> int:
    serve(args.host, args.port, [Path(r) for r in args.runs])
    return 0


def add_browse_parser(sub) -> None:
    q = sub.add_parser(
        "browse", help="a local web page: tasks, datasets, episodes with their frames and rewards, benchmark runs"
    )
    q.add_argument("runs", nargs="*", metavar="RUN_DIR", help="`d5rl bench` run directories to show side by side")
    q.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT})")
    q.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    q.set_defaults(func=cmd_browse)
