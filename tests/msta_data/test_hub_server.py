"""The hub server driven by the real huggingface_hub client over HTTP on 127.0.0.1."""

from __future__ import annotations

import hashlib
import http.client
import json
import logging
import os
from pathlib import Path

import pytest
from huggingface_hub import HfApi, get_hf_file_metadata, hf_hub_url
from huggingface_hub.errors import (
    EntryNotFoundError,
    HfHubHTTPError,
    RepositoryNotFoundError,
    RevisionNotFoundError,
)

from msta.data.hub_server import HubServer, ServerConfig

ALICE, BOB = "alice-secret-0001", "bob-secret-00002"


@pytest.fixture
def server(tmp_path):
    srv = HubServer(ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{ALICE}", f"bob:{BOB}"],
                                 orgs=["lab:alice"])).start()
    yield srv
    srv.stop()


def _api(server: HubServer, token: str | bool) -> HfApi:
    return HfApi(endpoint=server.url, token=token)


def _folder(tmp_path: Path, name: str, files: dict[str, bytes]) -> Path:
    root = tmp_path / name
    for rel, data in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    return root


def test_upload_refs_tree_info_download(server, tmp_path):
    api = _api(server, ALICE)
    url = api.create_repo("alice/m")
    assert url.repo_id == "alice/m" and url.endpoint == server.url
    src = _folder(tmp_path, "v1", {"config.json": b'{"a": 1}', "sub/w.safetensors": os.urandom(3000)})
    c1 = api.upload_folder(repo_id="alice/m", folder_path=src, commit_message="first").oid
    api.create_tag("alice/m", tag="v1", revision=c1)
    api.create_branch("alice/m", branch="exp", revision=c1)
    (src / "config.json").write_bytes(b'{"a": 2}')
    c2 = api.upload_folder(repo_id="alice/m", folder_path=src, commit_message="second").oid
    assert c1 != c2

    refs = api.list_repo_refs("alice/m")
    assert {b.name: b.target_commit for b in refs.branches} == {"main": c2, "exp": c1}
    assert {t.name: t.target_commit for t in refs.tags} == {"v1": c1}
    assert api.list_repo_files("alice/m") == ["config.json", "sub/w.safetensors"]
    tree = {e.path: e for e in api.list_repo_tree("alice/m", recursive=True, expand=True)}
    assert set(tree) == {"config.json", "sub", "sub/w.safetensors"}
    assert tree["config.json"].blob_id == hashlib.sha1(b'blob 8\0{"a": 2}').hexdigest()
    assert tree["config.json"].last_commit.oid == c2 and tree["sub/w.safetensors"].last_commit.oid == c1
    infos = api.get_paths_info("alice/m", ["config.json", "sub", "missing"], revision="v1")
    assert [i.path for i in infos] == ["config.json", "sub"]
    info = api.model_info("alice/m", revision=c1[:7])
    assert info.sha == c1 and sorted(s.rfilename for s in info.siblings) == ["config.json", "sub/w.safetensors"]
    assert [c.commit_id for c in api.list_repo_commits("alice/m")][:2] == [c2, c1]

    for rev, expected in (("v1", b'{"a": 1}'), ("exp", b'{"a": 1}'), ("main", b'{"a": 2}'), (c1, b'{"a": 1}'),
                          (c2[:10], b'{"a": 2}')):
        path = api.hf_hub_download("alice/m", "config.json", revision=rev, local_dir=tmp_path / f"dl-{rev}")
        assert Path(path).read_bytes() == expected
    assert api.file_exists("alice/m", "sub/w.safetensors") and not api.file_exists("alice/m", "nope")
    with pytest.raises(EntryNotFoundError):
        api.hf_hub_download("alice/m", "nope.txt", local_dir=tmp_path / "x")
    with pytest.raises(RevisionNotFoundError):
        api.model_info("alice/m", revision="no-such-branch")

    api.delete_tag("alice/m", tag="v1")
    api.delete_branch("alice/m", branch="exp")
    refs = api.list_repo_refs("alice/m")
    assert refs.tags == [] and [b.name for b in refs.branches] == ["main"]
    api.delete_file("sub/w.safetensors", repo_id="alice/m")
    assert api.list_repo_files("alice/m") == ["config.json"]
    api.delete_repo("alice/m")
    assert not api.repo_exists("alice/m")


def test_head_headers_and_range(server, tmp_path):
    api = _api(server, ALICE)
    api.create_repo("alice/h")
    data = os.urandom(1000)
    sha = api.upload_file(path_or_fileobj=data, path_in_repo="w.bin", repo_id="alice/h",
                          commit_message="w").oid
    conn = http.client.HTTPConnection("127.0.0.1", server.port)
    conn.request("HEAD", "/alice/h/resolve/main/w.bin")
    r = conn.getresponse()
    r.read()
    assert r.status == 200 and r.getheader("X-Repo-Commit") == sha
    assert r.getheader("ETag") == '"' + hashlib.sha1(b"blob 1000\0" + data).hexdigest() + '"'
    assert r.getheader("Content-Length") == "1000"
    conn.request("GET", "/alice/h/resolve/main/w.bin", headers={"Range": "bytes=10-19"})
    r = conn.getresponse()
    assert r.status == 206 and r.read() == data[10:20]


def test_private_repo_refused_to_anonymous_wrong_token_and_other_users(server, tmp_path):
    owner = _api(server, ALICE)
    owner.create_repo("alice/secret", private=True)
    owner.upload_file(path_or_fileobj=b"x", path_in_repo="a.txt", repo_id="alice/secret")
    assert owner.model_info("alice/secret").private is True
    with pytest.raises(RepositoryNotFoundError) as anon:
        _api(server, False).model_info("alice/secret")
    assert anon.value.response.status_code == 401
    with pytest.raises(RepositoryNotFoundError) as other:
        _api(server, BOB).model_info("alice/secret")
    assert other.value.response.status_code == 404
    with pytest.raises(HfHubHTTPError) as wrong:
        _api(server, "not-a-valid-token").model_info("alice/secret")
    assert wrong.value.response.status_code == 401
    with pytest.raises(RepositoryNotFoundError):
        _api(server, False).hf_hub_download("alice/secret", "a.txt", local_dir=tmp_path / "anon")
    assert not (tmp_path / "anon" / "a.txt").exists()
    # a public repo is readable anonymously, but a wrong token is still refused
    owner.create_repo("alice/open")
    assert _api(server, False).model_info("alice/open").private is False
    with pytest.raises(HfHubHTTPError) as wrong_public:
        _api(server, "not-a-valid-token").model_info("alice/open")
    assert wrong_public.value.response.status_code == 401
    owner.update_repo_settings("alice/open", private=True)
    with pytest.raises(RepositoryNotFoundError):
        _api(server, False).model_info("alice/open")


def test_writes_refused_without_token_or_rights(server):
    owner = _api(server, ALICE)
    owner.create_repo("alice/w")
    anon, bob = _api(server, False), _api(server, BOB)
    with pytest.raises(HfHubHTTPError) as e:
        anon.create_repo("alice/new")
    assert e.value.response.status_code == 401
    with pytest.raises(HfHubHTTPError) as e:
        anon.upload_file(path_or_fileobj=b"x", path_in_repo="x", repo_id="alice/w")
    assert e.value.response.status_code == 401
    with pytest.raises(HfHubHTTPError) as e:
        bob.upload_file(path_or_fileobj=b"x", path_in_repo="x", repo_id="alice/w")
    assert e.value.response.status_code == 403
    with pytest.raises(HfHubHTTPError) as e:
        bob.create_repo("alice/bobs")
    assert e.value.response.status_code == 403
    with pytest.raises(HfHubHTTPError) as e:
        bob.create_tag("alice/w", tag="t")
    assert e.value.response.status_code == 403
    with pytest.raises(HfHubHTTPError) as e:
        bob.delete_repo("alice/w")
    assert e.value.response.status_code == 403
    assert owner.list_repo_files("alice/w") == [] and owner.list_repo_refs("alice/w").tags == []
    # organisation members write in the organisation's namespace, others don't
    owner.create_repo("lab/shared")
    with pytest.raises(HfHubHTTPError) as e:
        bob.create_repo("lab/bob")
    assert e.value.response.status_code == 403
    assert [o["name"] for o in owner.whoami()["orgs"]] == ["lab"]


def test_create_repo_exist_ok_and_conflict(server):
    api = _api(server, ALICE)
    first = api.create_repo("alice/dup", repo_type="dataset")
    again = api.create_repo("alice/dup", repo_type="dataset", exist_ok=True)
    assert again == first and again.repo_type == "dataset"
    with pytest.raises(HfHubHTTPError) as e:
        api.create_repo("alice/dup", repo_type="dataset")
    assert e.value.response.status_code == 409 and e.value.response.json()["url"] == str(first)


def test_dataset_readme_goes_through_validate_yaml(server, tmp_path, caplog):
    api = _api(server, ALICE)
    api.create_repo("alice/ds", repo_type="dataset")
    good = _folder(tmp_path, "ds", {"README.md": b"---\ntags: [LeRobot]\n---\n# ds\n",
                                    "meta/info.json": b'{"codebase_version": "v3.0"}'})
    with caplog.at_level(logging.INFO, logger="msta.data.hub_server"):
        api.upload_folder(repo_id="alice/ds", repo_type="dataset", folder_path=good)
    assert "POST /api/validate-yaml -> 200" in caplog.text
    assert api.dataset_info("alice/ds").card_data.tags == ["LeRobot"]
    bad = _folder(tmp_path, "bad", {"README.md": b"---\ntags: [unclosed\n---\n"})
    with pytest.raises(ValueError, match="Invalid metadata in README.md"):
        api.upload_folder(repo_id="alice/ds", repo_type="dataset", folder_path=bad)
    assert sorted(api.list_repo_files("alice/ds", repo_type="dataset")) == ["README.md", "meta/info.json"]


def test_restart_keeps_repos_commits_and_refs(tmp_path):
    cfg = ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{ALICE}"])
    with HubServer(cfg) as srv:
        api = _api(srv, ALICE)
        api.create_repo("alice/p", private=True)
        sha = api.upload_file(path_or_fileobj=b"kept", path_in_repo="k.txt", repo_id="alice/p").oid
        api.create_tag("alice/p", tag="t1", revision=sha)
    with HubServer(cfg) as srv:
        api = _api(srv, ALICE)
        assert api.model_info("alice/p", revision="t1").sha == sha
        assert Path(api.hf_hub_download("alice/p", "k.txt", revision="t1", local_dir=tmp_path / "d")).read_bytes() \
            == b"kept"
        with pytest.raises(RepositoryNotFoundError):
            _api(srv, False).model_info("alice/p")


def test_root_is_locked_against_a_second_server(server):
    with pytest.raises(ValueError, match="in use by another msta-hub server"):
        HubServer(ServerConfig(root=server.config.root))


def test_error_bodies_are_read_and_connection_kept_alive(server):
    conn = http.client.HTTPConnection("127.0.0.1", server.port)
    body = b'{"key": "header"}\n' * 50_000  # ~1 MB refused before it is parsed
    conn.request("POST", "/api/models/alice/none/commit/main", body=body,
                 headers={"Authorization": "Bearer wrong-token-123"})
    r = conn.getresponse()
    assert r.status == 401 and "Invalid credentials" in json.loads(r.read())["error"]
    conn.request("GET", "/api/whoami-v2", headers={"Authorization": f"Bearer {ALICE}"})
    r = conn.getresponse()
    assert r.status == 200 and json.loads(r.read())["name"] == "alice"


def test_more_client_calls(server, tmp_path):
    api = _api(server, ALICE)
    api.create_repo("alice/more", repo_type="dataset")
    src = _folder(tmp_path, "more", {"a/x.txt": b"x", "a/y.txt": b"y", "b.txt": b"b"})
    c1 = api.upload_folder(repo_id="alice/more", repo_type="dataset", folder_path=src).oid
    assert api.revision_exists("alice/more", c1, repo_type="dataset")
    assert not api.revision_exists("alice/more", "nope", repo_type="dataset")
    assert api.resolve_revision("alice/more", repo_type="dataset", revision="main",
                                cache_dir=tmp_path / "cache").resolved == c1
    meta = get_hf_file_metadata(hf_hub_url("alice/more", "b.txt", repo_type="dataset", endpoint=server.url),
                                token=ALICE)
    assert meta.commit_hash == c1 and meta.size == 1 and meta.etag == hashlib.sha1(b"blob 1\0b").hexdigest()
    api.create_branch("alice/more", branch="dev", repo_type="dataset")
    api.create_branch("alice/more", branch="dev", repo_type="dataset", exist_ok=True)
    with pytest.raises(HfHubHTTPError) as e:
        api.create_branch("alice/more", branch="dev", repo_type="dataset")
    assert e.value.response.status_code == 409
    c2 = api.delete_folder("a", repo_id="alice/more", repo_type="dataset", parent_commit=c1).oid
    assert api.list_repo_files("alice/more", repo_type="dataset") == ["b.txt"]
    with pytest.raises(HfHubHTTPError) as e:  # stale parent commit
        api.upload_file(path_or_fileobj=b"z", path_in_repo="z.txt", repo_id="alice/more", repo_type="dataset",
                        parent_commit=c1)
    assert e.value.response.status_code == 412
    assert api.list_repo_files("alice/more", repo_type="dataset", revision="dev") == ["a/x.txt", "a/y.txt", "b.txt"]
    assert api.dataset_info("alice/more").sha == c2
