"""The viewer against hostile use (issue 30): foreign Host (DNS rebinding), cross-site POST,
a POST without the page's token, malformed requests; and a hypothesis fuzz of raw HTTP
requests. A sensor-less LiveView counts state changes, so every test is fast."""

from __future__ import annotations

import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from viewer_kit import CountingLive, http, raw_request

from thintact_sdk.apps.viewer import ViewerServer
from thintact_sdk.apps.viewer.server import MAX_BODY_BYTES, TOKEN_HEADER


@pytest.fixture(scope="module")
def served():
    live = CountingLive()
    with ViewerServer(port=0) as server:
        server.start(live)
        yield server, live
    assert not server.internal_errors


def _page_token(port: int) -> str:
    status, reply = http(port, "GET", "/")
    assert status == 200
    match = re.search(rb'<meta name="thintact-token" content="([^"]+)">', reply)
    assert match, reply[:400]
    return match.group(1).decode()


def test_page_carries_the_token_and_forbids_framing(served):
    server, _ = served
    assert _page_token(server.port) == server.token
    _, reply = http(server.port, "GET", "/")
    head = reply.split(b"\r\n\r\n", 1)[0].decode("latin-1")
    assert "X-Frame-Options: DENY" in head and "frame-ancestors 'none'" in head
    nonce = re.search(r"script-src 'nonce-([^']+)'", head).group(1)
    assert f'<script nonce="{nonce}">'.encode() in reply  # the page's own script may run


@pytest.mark.parametrize("host", ["127.0.0.1:{port}", "localhost:{port}", "LOCALHOST:{port}",
                                  "[::1]:{port}"])
def test_own_loopback_hosts_are_served(served, host):
    server, _ = served
    status, _ = http(server.port, "GET", "/stats.json", host=host.format(port=server.port))
    assert status == 200


@pytest.mark.parametrize("host", ["evil.example:{port}", "127.0.0.1", "127.0.0.1:{other}",
                                  "localhost.evil.example:{port}", "0.0.0.0:{port}", "",
                                  "127.0.0.1:{port}.evil.example", None])
@pytest.mark.parametrize("path", ["/", "/stats.json", "/frame.jpg"])
def test_foreign_host_is_forbidden(served, host, path):
    """DNS rebinding: a page from evil.example resolved to 127.0.0.1 sends its own Host."""
    server, live = served
    before = live.changes
    if host is not None:
        host = host.format(port=server.port, other=server.port + 1)
    status, reply = http(server.port, "GET", path, host=host)
    assert status == 403 and b"thintact-token" not in reply and server.token.encode() not in reply
    status, _ = http(server.port, "POST", "/reset", {TOKEN_HEADER: server.token}, host=host)
    assert status == 403 and live.changes == before


def test_post_needs_the_token(served):
    server, live = served
    before = live.changes
    for headers in ({}, {TOKEN_HEADER: ""}, {TOKEN_HEADER: "x" * len(server.token)},
                    {TOKEN_HEADER: server.token[:-1]}, {TOKEN_HEADER: server.token + "x"},
                    {TOKEN_HEADER.lower() + "s": server.token}):
        status, reply = http(server.port, "POST", "/reset", headers)
        assert status == 403 and TOKEN_HEADER.encode() in reply, headers
    assert live.changes == before
    status, _ = http(server.port, "POST", "/reset", {TOKEN_HEADER: server.token})
    assert status == 200 and live.changes == before + 1


@pytest.mark.parametrize("path", ["/reset", "/snapshot", "/record/start", "/record/stop"])
def test_every_state_change_needs_the_token_and_the_origin(served, path):
    server, live = served
    before = live.changes
    assert http(server.port, "POST", path)[0] == 403
    assert http(server.port, "POST", path, {"Origin": "http://evil.example",
                                            TOKEN_HEADER: server.token})[0] == 403
    assert http(server.port, "POST", path, host=f"evil.example:{server.port}",
                headers={TOKEN_HEADER: server.token})[0] == 403
    assert http(server.port, "GET", path, {TOKEN_HEADER: server.token})[0] == 404  # only POST acts
    assert live.changes == before
    assert http(server.port, "POST", path, {TOKEN_HEADER: server.token})[0] == 200
    assert live.changes == before + 1


@pytest.mark.parametrize("origin", ["http://evil.example", "null", "https://127.0.0.1:{port}",
                                    "http://127.0.0.1:{other}", "http://127.0.0.1:{port}.evil"])
def test_cross_origin_post_is_forbidden_even_with_the_token(served, origin):
    server, live = served
    before = live.changes
    origin = origin.format(port=server.port, other=server.port + 1)
    status, reply = http(server.port, "POST", "/reset", {TOKEN_HEADER: server.token, "Origin": origin})
    assert status == 403 and b"cross-origin" in reply and live.changes == before
    status, _ = http(server.port, "POST", "/reset",
                     {TOKEN_HEADER: server.token, "Sec-Fetch-Site": "cross-site"})
    assert status == 403 and live.changes == before


def test_same_origin_post_with_the_token_resets(served):
    server, live = served
    before = live.changes
    for origin in (f"http://127.0.0.1:{server.port}", f"http://localhost:{server.port}"):
        status, _ = http(server.port, "POST", "/reset", {TOKEN_HEADER: server.token, "Origin": origin,
                                                          "Sec-Fetch-Site": "same-origin"})
        assert status == 200
    assert live.changes == before + 2


def test_other_methods_and_bad_bodies_change_nothing(served):
    server, live = served
    before = live.changes
    token = {TOKEN_HEADER: server.token}
    for method in ("PUT", "DELETE", "PATCH", "OPTIONS"):
        assert http(server.port, method, "/reset", token)[0] == 405
        assert http(server.port, method, "/reset")[0] == (405 if method == "OPTIONS" else 403)
    assert http(server.port, "BREW", "/reset", token)[0] == 501
    assert http(server.port, "POST", "/reset", {**token, "Content-Length": "12"}, body=b"")[0] == 400
    big = {**token, "Content-Length": str(MAX_BODY_BYTES + 1)}
    assert raw_request(server.port, (f"POST /reset HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n"
                                     + "".join(f"{k}: {v}\r\n" for k, v in big.items())
                                     + "\r\n").encode())[0] == 413
    assert http(server.port, "POST", "/nothing", token)[0] == 404
    assert live.changes == before
    assert http(server.port, "POST", "/reset", token, body=b"x" * 1000)[0] == 200  # body ignored
    assert live.changes == before + 1


def test_two_servers_have_different_tokens():
    with ViewerServer(port=0) as a, ViewerServer(port=0) as b:
        assert a.token != b.token and len(a.token) >= 32


# -- fuzz ---------------------------------------------------------------------------------

_TOKEN = object()  # stands for the server's own token in generated headers
_HOST = object()  # stands for the server's own Host


def _header_text():
    return st.one_of(
        st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=40),
        st.text(st.characters(min_codepoint=1, max_codepoint=255), max_size=40),
        st.integers(0, 70_000).map(lambda n: "a" * n),  # around the 64 KiB line limit
    )


requests = st.fixed_dictionaries({
    "method": st.one_of(st.sampled_from(["GET", "POST", "PUT", "DELETE", "PATCH", "OPTIONS", "HEAD",
                                         "get", "CONNECT", "TRACE"]),
                        st.text(st.characters(min_codepoint=33, max_codepoint=126), min_size=1,
                                max_size=12)),
    "path": st.one_of(st.sampled_from(["/", "/reset", "/frame.jpg?after=-5", "/stats.json",
                                       "/snapshot", "/record/start?sensor=0", "/record/stop",
                                       "/reset?sensor=1", "/stats.json?sensor=%FF",
                                       "/reset?x=1", "//[bad", "/frame.jpg?after=99999999999999999999",
                                       "*", "http://evil/reset", "/%00", "/../../etc/passwd"]),
                      st.text(st.characters(min_codepoint=33, max_codepoint=255), max_size=80)),
    "version": st.sampled_from(["HTTP/1.1", "HTTP/1.0", "HTTP/2.0", "HTTP/9", "", "FOO"]),
    "host": st.one_of(st.none(), st.just(_HOST), _header_text()),
    "origin": st.one_of(st.none(), st.just("http://127.0.0.1:{port}"), _header_text()),
    "token": st.one_of(st.none(), st.just(_TOKEN), _header_text()),
    "extra": st.lists(st.tuples(st.text(st.characters(min_codepoint=33, max_codepoint=126,
                                                      exclude_characters=":"), min_size=1, max_size=20),
                                _header_text()), max_size=4),
    "body": st.binary(max_size=2048),
    "content_length": st.one_of(st.none(), st.just("auto"), st.sampled_from(["-1", "abc", "1e3", "0",
                                                                             "99999999999"])),
})


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(req=requests)
def test_fuzzed_requests_never_crash_500_or_change_state_without_the_token(served, req):
    server, live = served
    port = server.port
    before = live.changes
    lines = [f"{req['method']} {req['path']} {req['version']}".rstrip()]
    if req["host"] is not None:
        lines.append(f"Host: {f'127.0.0.1:{port}' if req['host'] is _HOST else req['host']}")
    if req["origin"] is not None:
        lines.append(f"Origin: {req['origin'].format(port=port) if '{port}' in req['origin'] else req['origin']}")
    if req["token"] is not None:
        lines.append(f"{TOKEN_HEADER}: {server.token if req['token'] is _TOKEN else req['token']}")
    lines += [f"{k}: {v}" for k, v in req["extra"]]
    if req["content_length"] is not None:
        cl = str(len(req["body"])) if req["content_length"] == "auto" else req["content_length"]
        lines.append(f"Content-Length: {cl}")
    data = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1", "replace") + req["body"]
    status, _ = raw_request(port, data)
    assert status != 500
    assert status is None or 200 <= status < 600
    token_sent = req["token"] is _TOKEN and req["host"] is _HOST
    assert live.changes - before <= (1 if token_sent else 0)
    assert not server.internal_errors
    # still serving
    assert http(port, "GET", "/stats.json")[0] == 200
