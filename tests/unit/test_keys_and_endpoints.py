"""Key prefixes and Zenoh endpoints as the command line checks them: good ones pass, bad ones
are named."""

from __future__ import annotations

import pytest

from common.keys import Keys
from common.session import check_endpoints


def test_endpoints_are_checked_by_zenohs_parser() -> None:
    assert check_endpoints("tcp/127.0.0.1:7447") == ["tcp/127.0.0.1:7447"]
    assert check_endpoints("tcp/a:1, udp/b:2") == ["tcp/a:1", "udp/b:2"]
    for bad, named in (("foo", "'foo'"), ("tcp/a:1,,tcp/b:2", "''"), ("", "''")):
        with pytest.raises(ValueError, match=f"invalid endpoint {named}: expected <protocol>/"):
            check_endpoints(bad)


def test_good_prefixes_pass() -> None:
    for prefix in ("umay/umay1", "test/3f2a9c", "robot-2/arm_left"):
        assert Keys(prefix).twist == f"{prefix}/controller/twist"
