"""The I/O-free parts of the client: retry policy, option handling, decoding."""

from __future__ import annotations

import base64

import httpx
import numpy as np
import pytest

from neural_shdf.client.operations import RetryPolicy, as_query, given
from neural_shdf.client.results import decode_labels, decode_shdf


def response(status: int, **headers: str) -> httpx.Response:
    return httpx.Response(status, headers=headers)


def test_backoff_doubles_up_to_its_cap_and_honours_retry_after():
    policy = RetryPolicy(retries=6, backoff_s=0.5, max_backoff_s=4.0)
    delays = [policy.delay(attempt, response(503)) for attempt in range(6)]
    assert delays == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    assert policy.delay(0, response(503, **{"Retry-After": "3"})) == 3.0
    assert policy.delay(0, response(503, **{"Retry-After": "600"})) == 4.0


@pytest.mark.parametrize(
    ("outcome", "retried"),
    [
        (response(503), True),
        (response(504), True),
        (response(502), True),
        (response(500), False),
        (response(422), False),
        (response(404), False),
        (httpx.ReadTimeout("slow"), True),
        (httpx.ConnectError("refused"), True),
        (httpx.UnsupportedProtocol("ftp"), False),
    ],
)
def test_only_transient_failures_are_retried(outcome, retried):
    policy = RetryPolicy(retries=2)
    assert policy.should_retry(0, outcome) is retried
    assert not policy.should_retry(2, outcome)


def test_options_drop_defaults_and_encode_booleans():
    options = given({"clusters": 4, "smoothing": None, "refine": True, "parts": None})
    assert options == {"clusters": 4, "refine": True}
    assert as_query(options) == {"clusters": "4", "refine": "true"}


def test_labels_and_shdf_decode_from_their_binary_forms():
    labels = np.array([0, 3, 300, -1], dtype="<i2")
    body = {"labels_base64": base64.b64encode(labels.tobytes()).decode(), "labels_dtype": "int16"}
    assert decode_labels(body).tolist() == [0, 3, 300, -1]
    assert decode_labels({"labels": [1, 2]}).dtype == np.int32
    values = np.array([0.25, np.nan], dtype="<f4")
    decoded = decode_shdf(values.tobytes(), faces=2)
    assert decoded[0] == np.float32(0.25) and np.isnan(decoded[1])
    with pytest.raises(ValueError, match="3 faces"):
        decode_shdf(values.tobytes(), faces=3)


def test_the_labeller_list_follows_every_page():
    from neural_shdf.client.operations import list_labelers

    def info(index: int) -> dict:
        return {
            "labeler_id": f"{index:064x}",
            "label_names": ["neck", "ball"],
            "label_values": [2, 5],
            "feature_version": 3,
            "smoothing": 0.003,
            "training_meshes": 2,
            "size_bytes": 100,
            "stored_at": 1.0,
        }

    pages = [
        {"labelers": [info(0), info(1)], "total": 3, "next_offset": 2},
        {"labelers": [info(2)], "total": 3, "next_offset": None},
    ]
    operation = list_labelers()
    call = next(operation)
    offsets = []
    with pytest.raises(StopIteration) as done:
        for page in pages:
            offsets.append(call.params["offset"])
            assert (call.method, call.path) == ("GET", "/v1/labelers")
            call = operation.send(
                httpx.Response(200, json=page, request=httpx.Request("GET", "http://x"))
            )
    assert offsets == [0, 2]
    assert [entry.labeler_id for entry in done.value.value] == [f"{i:064x}" for i in range(3)]
