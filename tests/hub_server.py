"""A minimal, in-memory Hugging Face Hub on 127.0.0.1 for tests that drive the real huggingface_hub client.

It implements only what `HfApi.create_repo` / `upload_folder` / `hf_hub_download` call (huggingface_hub 0.35):

    POST /api/repos/create                               create a model repo (409 if it exists)
    POST /api/validate-yaml                              README.md metadata check (always valid)
    GET  /api/models/{ns}/{name}[/revision/{rev}]        repo info (sha, siblings, xetEnabled=False)
    POST /api/models/{ns}/{name}/preupload/{rev}         upload modes: "lfs" for *.safetensors/*.bin, else "regular"
    POST /{ns}/{name}.git/info/lfs/objects/batch         LFS batch API: a PUT target per missing object
    PUT  /__lfs__/{sha256}                               LFS object upload (sha256 and size verified)
    POST /api/models/{ns}/{name}/commit/{rev}            JSON-lines commit: header, file (base64), lfsFile, deletedFile
    HEAD/GET /{ns}/{name}/resolve/{rev}/{path}           file metadata / download, by branch name or commit sha

Every write needs an `Authorization: Bearer ...` header. The server binds 127.0.0.1 only and keeps a log of
requests and commits for assertions. Start it with `HubServer().start()`; `stop()` shuts it down.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import threading
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, unquote, urlsplit

LFS_SUFFIXES = (".safetensors", ".bin", ".pt", ".pth", ".ckpt")
REPO = r"(?P<repo>[^/]+/[^/]+?)"


def git_blob_sha1(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


@dataclass
class Commit:
    sha: str
    summary: str
    files: dict[str, bytes]  # snapshot of the whole repo after the commit
    changed: list[str]  # paths added or modified by this commit
    lfs: set[str]  # paths (of the snapshot) stored through LFS


@dataclass
class Repo:
    repo_id: str
    commits: list[Commit] = field(default_factory=list)

    @property
    def head(self) -> Commit | None:
        return self.commits[-1] if self.commits else None

    def at(self, revision: str) -> Commit | None:
        if revision == "main":
            return self.head
        return next((c for c in self.commits if c.sha == revision), None)


class HubServer:
    """In-memory Hub served by a daemon thread on 127.0.0.1 (port chosen by the OS)."""

    def __init__(self):
        self.repos: dict[str, Repo] = {}
        self.lfs_objects: dict[str, bytes] = {}
        self.log: list[tuple[str, str]] = []  # (method, path) of every request
        self.validated_yaml: list[str] = []  # README.md contents sent to /api/validate-yaml
        self.lock = threading.Lock()
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host, port = self._httpd.server_address[:2]
        return f"http://{host}:{port}"

    def start(self) -> HubServer:
        hub = self

        class Handler(_Handler):
            server_hub = hub

        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._thread.join(timeout=5)
            self._httpd = None

    def __enter__(self) -> HubServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ----- helpers for assertions -----------------------------------------------------------------------

    def files(self, repo_id: str, revision: str = "main") -> dict[str, bytes]:
        commit = self.repos[repo_id].at(revision)
        return {} if commit is None else dict(commit.files)

    def commits(self, repo_id: str) -> list[Commit]:
        return list(self.repos[repo_id].commits)


class _Handler(BaseHTTPRequestHandler):
    server_hub: HubServer
    protocol_version = "HTTP/1.1"

    def log_message(self, *args) -> None:  # keep test output quiet
        pass

    # ----- plumbing -------------------------------------------------------------------------------------

    def _body(self) -> bytes:
        if self.headers.get("Transfer-Encoding", "").lower() == "chunked":
            out = bytearray()
            while True:
                size = int(self.rfile.readline().split(b";")[0].strip() or b"0", 16)
                if size == 0:
                    while self.rfile.readline() not in (b"\r\n", b"\n", b""):
                        pass
                    return bytes(out)
                out += self.rfile.read(size)
                self.rfile.readline()
        return self.rfile.read(int(self.headers.get("Content-Length") or 0))

    def _send(self, status: int, body: bytes = b"", headers: dict | None = None, head: bool = False) -> None:
        self.send_response(status)
        headers = {"Content-Type": "application/json", **(headers or {})}
        for key, value in headers.items():
            self.send_header(key, value)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        if not head:
            self.wfile.write(body)

    def _json(self, status: int, payload, headers: dict | None = None) -> None:
        self._send(status, json.dumps(payload).encode(), headers)

    def _error(self, status: int, message: str, code: str | None = None, head: bool = False) -> None:
        headers = {"X-Error-Message": message, **({"X-Error-Code": code} if code else {})}
        self._send(status, b"" if head else json.dumps({"error": message}).encode(), headers, head=head)

    def _authorized(self) -> bool:
        if self.headers.get("Authorization", "").startswith("Bearer "):
            return True
        self._error(401, "Invalid credentials in Authorization header")
        return False

    def _route(self, method: str) -> None:
        hub = self.server_hub
        parts = urlsplit(self.path)
        path, query = unquote(parts.path), parse_qs(parts.query)
        with hub.lock:
            hub.log.append((method, path))
        for pattern, handler in self._ROUTES.get(method, ()):
            match = re.fullmatch(pattern, path)
            if match:
                with hub.lock:
                    return handler(self, query=query, **match.groupdict())
        if method in ("POST", "PUT"):
            self._body()  # drain it: the connection is kept alive
        self._error(404, f"No route for {method} {path}", head=method == "HEAD")

    def do_GET(self):  # noqa: N802
        self._route("GET")

    def do_HEAD(self):  # noqa: N802
        self._route("HEAD")

    def do_POST(self):  # noqa: N802
        self._route("POST")

    def do_PUT(self):  # noqa: N802
        self._route("PUT")

    # ----- endpoints ------------------------------------------------------------------------------------

    def _repo_or_404(self, repo_id: str, head: bool = False) -> Repo | None:
        repo = self.server_hub.repos.get(repo_id)
        if repo is None:
            self._error(404, "Repository not found", "RepoNotFound", head=head)
        return repo

    def create_repo(self, query) -> None:
        payload = json.loads(self._body() or b"{}")
        if not self._authorized():
            return
        if payload.get("type", "model") != "model":
            return self._error(400, "This test hub only hosts model repos")
        repo_id = "/".join(p for p in (payload.get("organization"), payload["name"]) if p)
        if "/" not in repo_id:
            repo_id = f"test-user/{repo_id}"  # the Hub puts a bare name under the token's user
        url = f"{self.server_hub.url}/{repo_id}"
        if repo_id in self.server_hub.repos:
            return self._json(409, {"error": "You already created this model repo", "url": url})
        self.server_hub.repos[repo_id] = Repo(repo_id)
        self._json(200, {"url": url, "name": repo_id, "id": repo_id})

    def validate_yaml(self, query) -> None:
        body = self._body()
        try:
            content = json.loads(body).get("content", "")
        except ValueError:  # RepoCard.validate posts a form, not JSON
            content = parse_qs(body.decode()).get("content", [""])[0]
        self.server_hub.validated_yaml.append(content)
        self._json(200, {"errors": [], "warnings": []})

    def repo_info(self, query, repo: str, rev: str = "main") -> None:
        found = self._repo_or_404(repo)
        if found is None:
            return
        commit = found.at(rev)
        if commit is None and rev != "main":
            return self._error(404, f"Invalid rev id: {rev}", "RevisionNotFound")
        files = commit.files if commit else {}
        self._json(200, {
            "id": repo, "modelId": repo, "sha": commit.sha if commit else None, "private": False,
            "xetEnabled": False, "siblings": [{"rfilename": p} for p in sorted(files)],
        })

    def preupload(self, query, repo: str, rev: str) -> None:
        payload = json.loads(self._body())
        if not self._authorized() or self._repo_or_404(repo) is None:
            return
        files = [
            {"path": f["path"], "uploadMode": "lfs" if f["path"].endswith(LFS_SUFFIXES) else "regular",
             "shouldIgnore": False, "oid": None}
            for f in payload["files"]
        ]
        head = self.server_hub.repos[repo].head
        self._json(200, {"files": files, "commitOid": head.sha if head else None})

    def lfs_batch(self, query, repo: str) -> None:
        payload = json.loads(self._body())
        if not self._authorized() or self._repo_or_404(repo) is None:
            return
        objects = []
        for obj in payload["objects"]:
            entry = {"oid": obj["oid"], "size": obj["size"]}
            if obj["oid"] not in self.server_hub.lfs_objects:
                entry["actions"] = {"upload": {"href": f"{self.server_hub.url}/__lfs__/{obj['oid']}", "header": {}}}
            objects.append(entry)
        self._json(200, {"transfer": "basic", "objects": objects}, {"Content-Type": "application/vnd.git-lfs+json"})

    def lfs_put(self, query, oid: str) -> None:
        data = self._body()
        if hashlib.sha256(data).hexdigest() != oid:
            return self._error(400, "LFS object does not match its sha256")
        self.server_hub.lfs_objects[oid] = data
        self._send(200)

    def commit(self, query, repo: str, rev: str) -> None:
        body = self._body()
        if not self._authorized():
            return
        found = self._repo_or_404(repo)
        if found is None:
            return
        if rev != "main":
            return self._error(400, "This test hub only commits to main", "RevisionNotFound")
        head = found.head
        files, lfs = (dict(head.files), set(head.lfs)) if head else ({}, set())
        summary, changed = "", []
        for line in body.splitlines():
            if not line.strip():
                continue
            item = json.loads(line)
            key, value = item["key"], item["value"]
            if key == "header":
                summary = value.get("summary", "")
                parent = value.get("parentCommit")
                if parent and head and parent != head.sha:
                    return self._error(412, "parentCommit is not the head of the branch")
            elif key == "file":
                if value.get("encoding", "base64") != "base64":
                    return self._error(400, f"Unsupported encoding {value.get('encoding')!r}")
                files[value["path"]] = base64.b64decode(value["content"])
                lfs.discard(value["path"])
                changed.append(value["path"])
            elif key == "lfsFile":
                data = self.server_hub.lfs_objects.get(value["oid"])
                if data is None:
                    return self._error(400, f"LFS object {value['oid']} was never uploaded")
                files[value["path"]] = data
                lfs.add(value["path"])
                changed.append(value["path"])
            elif key == "deletedFile":
                if files.pop(value["path"], None) is None:
                    return self._error(404, "A file with this name doesn't exist", "EntryNotFound")
                lfs.discard(value["path"])
            else:
                return self._error(400, f"Unsupported commit operation {key!r}")
        sha = hashlib.sha1(
            json.dumps([head.sha if head else None, summary, sorted((p, git_blob_sha1(d)) for p, d in files.items())])
            .encode()
        ).hexdigest()
        found.commits.append(Commit(sha, summary, files, changed, lfs))
        self._json(200, {"commitUrl": f"{self.server_hub.url}/{repo}/commit/{sha}", "commitOid": sha,
                         "pullRequestUrl": None, "success": True})

    def resolve(self, query, repo: str, rev: str, path: str, head: bool = False) -> None:
        found = self._repo_or_404(repo, head=head)
        if found is None:
            return
        commit = found.at(rev)
        if commit is None:
            return self._error(404, f"Invalid rev id: {rev}", "RevisionNotFound", head=head)
        data = commit.files.get(path)
        if data is None:
            return self._error(404, "Entry not found", "EntryNotFound", head=head)
        headers = {"Content-Type": "application/octet-stream", "X-Repo-Commit": commit.sha,
                   "ETag": f'"{git_blob_sha1(data)}"'}
        if path in commit.lfs:
            headers.update({"X-Linked-Etag": f'"{hashlib.sha256(data).hexdigest()}"', "X-Linked-Size": str(len(data))})
        self._send(200, data, headers, head=head)

    def resolve_head(self, query, **kw) -> None:
        self.resolve(query, head=True, **kw)

    _ROUTES = {
        "POST": [
            (r"/api/repos/create", create_repo),
            (r"/api/validate-yaml", validate_yaml),
            (rf"/api/models/{REPO}/preupload/(?P<rev>[^/]+)", preupload),
            (rf"/api/models/{REPO}/commit/(?P<rev>[^/]+)", commit),
            (rf"/{REPO}\.git/info/lfs/objects/batch", lfs_batch),
        ],
        "PUT": [(r"/__lfs__/(?P<oid>[0-9a-f]{64})", lfs_put)],
        "GET": [
            (rf"/api/models/{REPO}/revision/(?P<rev>[^/]+)", repo_info),
            (rf"/api/models/{REPO}", repo_info),
            (rf"/{REPO}/resolve/(?P<rev>[^/]+)/(?P<path>.+)", resolve),
        ],
        "HEAD": [(rf"/{REPO}/resolve/(?P<rev>[^/]+)/(?P<path>.+)", resolve_head)],
    }
