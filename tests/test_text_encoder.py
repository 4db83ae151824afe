"""Text encoders: offline loading from the cache and from a fresh unpack, damaged parts, both backends agree."""

from __future__ import annotations

import io
import json
import socket
import zipfile

import numpy as np
import pytest

from mapping.perception.model_cache import ModelCacheError, Part, is_complete, unpack_split_zip
from mapping.perception.text_encoder import TextEncoder, TextEncoderError, model_folder


@pytest.fixture
def no_network(monkeypatch):
    """Any socket connection fails: loading must not touch the network."""
    def refuse(*args, **kwargs):
        raise OSError("network access attempted during an offline load")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def split_zip(tmp_path, files: dict[str, bytes], pieces: int = 3) -> list[Part]:
    """A zip of ``files`` under one top folder, cut into ``pieces`` files, with their sizes and hashes."""
    import hashlib

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(f"model/{name}", data)
    data = buf.getvalue()
    cut = np.linspace(0, len(data), pieces + 1).astype(int)
    parts = []
    for k in range(pieces):
        path = tmp_path / "parts" / f"model.zip.{k + 1:03d}"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data[cut[k]:cut[k + 1]])
        parts.append(Part(path, cut[k + 1] - cut[k], hashlib.sha256(data[cut[k]:cut[k + 1]]).hexdigest()))
    return parts


def tiny_bert_folder(tmp_path, real_folder) -> dict[str, bytes]:
    """Files of a 2-layer, 32-wide random BERT with MiniLM's tokenizer: loads like the real thing, fast."""
    from safetensors.numpy import save

    rng = np.random.default_rng(0)
    d, vocab, layers = 32, 30522, 2
    w = {"embeddings.word_embeddings.weight": (vocab, d), "embeddings.position_embeddings.weight": (512, d),
         "embeddings.token_type_embeddings.weight": (2, d), "embeddings.LayerNorm.weight": (d,),
         "embeddings.LayerNorm.bias": (d,)}
    for k in range(layers):
        p = f"encoder.layer.{k}."
        for name in ("attention.self.query", "attention.self.key", "attention.self.value", "attention.output.dense"):
            w[p + name + ".weight"], w[p + name + ".bias"] = (d, d), (d,)
        w[p + "intermediate.dense.weight"], w[p + "intermediate.dense.bias"] = (4 * d, d), (4 * d,)
        w[p + "output.dense.weight"], w[p + "output.dense.bias"] = (d, 4 * d), (d,)
        for ln in ("attention.output.LayerNorm", "output.LayerNorm"):
            w[p + ln + ".weight"], w[p + ln + ".bias"] = (d,), (d,)
    tensors = {k: (np.ones(s) if k.endswith("LayerNorm.weight") else rng.normal(0, 0.05, s)).astype(np.float32)
               for k, s in w.items()}
    config = {"model_type": "bert", "hidden_size": d, "num_attention_heads": 4, "num_hidden_layers": layers,
              "intermediate_size": 4 * d, "hidden_act": "gelu", "layer_norm_eps": 1e-12, "pad_token_id": 0}
    return {"config.json": json.dumps(config).encode(), "model.safetensors": save(tensors),
            "tokenizer.json": (real_folder / "tokenizer.json").read_bytes(),
            "sentence_bert_config.json": b'{"max_seq_length": 64}',
            "1_Pooling/config.json": b'{"word_embedding_dimension": 32, "pooling_mode_mean_tokens": true}'}


def test_fresh_unpack_is_atomic_verified_and_loads_offline(tmp_path, no_network):
    parts = split_zip(tmp_path, tiny_bert_folder(tmp_path, model_folder("minilm")))
    target = tmp_path / "cache" / "tiny"
    assert unpack_split_zip(parts, target) == target and is_complete(target)
    assert not [p for p in target.parent.iterdir() if p.name.startswith(".")]  # no temp folder left
    enc = TextEncoder("minilm", backend="numpy", folder=target)
    v = enc.encode(["a chair", "a lamp"])
    assert v.shape == (2, 32) and np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    (target / "model.safetensors").touch()  # a second call trusts the manifest and does not re-unpack
    assert unpack_split_zip(parts, target) == target


def test_damaged_or_missing_part_is_a_clear_error(tmp_path):
    parts = split_zip(tmp_path, {"a.txt": b"x" * 5000, "b.bin": bytes(range(256)) * 40})
    data = bytearray(parts[1].path.read_bytes())
    data[10] ^= 0xFF
    parts[1].path.write_bytes(bytes(data))
    with pytest.raises(ModelCacheError, match=r"damaged.*model\.zip\.002"):
        unpack_split_zip(parts, tmp_path / "cache" / "m")
    parts[1].path.unlink()
    with pytest.raises(ModelCacheError, match=r"missing.*model\.zip\.002"):
        unpack_split_zip(parts, tmp_path / "cache" / "m")
    unhashed = [Part(p.path) for p in split_zip(tmp_path / "again", {"a.txt": b"y" * 5000})]
    unhashed[0].path.write_bytes(b"not a zip at all" + unhashed[0].path.read_bytes()[16:])
    with pytest.raises(ModelCacheError, match="valid zip|damaged"):
        unpack_split_zip(unhashed, tmp_path / "cache" / "n")
    assert not (tmp_path / "cache" / "m").exists() and not (tmp_path / "cache" / "n").exists()


def test_broken_cache_copy_is_replaced(tmp_path):
    parts = split_zip(tmp_path, {"a.txt": b"z" * 3000})
    target = unpack_split_zip(parts, tmp_path / "cache" / "m")
    (target / "a.txt").write_bytes(b"short")  # damaged after unpacking: manifest sizes no longer match
    assert not is_complete(target)
    assert (unpack_split_zip(parts, target) / "a.txt").read_bytes() == b"z" * 3000


def test_unknown_encoder_or_backend_is_refused():
    with pytest.raises(TextEncoderError, match="unknown text encoder 'clip'"):
        TextEncoder("clip")
    with pytest.raises(TextEncoderError, match="backend"):
        TextEncoder("minilm", backend="onnx")


@pytest.mark.parametrize("name", ["mpnet", "minilm"])
def test_real_encoder_loads_offline_from_the_cache_and_both_backends_agree(name, no_network, capfd):
    texts = ["chair", "something to sit on", "lamp", "a queen-size bed with a honey brown wooden frame"]
    fast = TextEncoder(name, backend="numpy").encode(texts)
    capfd.readouterr()
    ref = TextEncoder(name, backend="torch").encode(texts)
    assert "Loading weights" not in capfd.readouterr().err  # no progress bar on every env or run
    assert fast.shape == ref.shape == (4, {"mpnet": 768, "minilm": 384}[name])
    np.testing.assert_allclose(fast, ref, atol=1e-5)  # code books and queries are interchangeable
    assert fast[0] @ fast[1] > fast[0] @ fast[2]  # "chair" is nearer "something to sit on" than "lamp"
