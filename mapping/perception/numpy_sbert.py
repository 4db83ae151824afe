"""A sentence-transformers model (BERT or MPNet encoder, mean pooling, unit length) run in NumPy.

Why: importing torch, transformers and sentence-transformers takes 4-5 s on a small CPU, longer than
the whole budget of one ``openmulti query``. The two models the project uses (all-MiniLM-L6-v2, a BERT,
and all-mpnet-base-v2, an MPNet) are plain transformer encoders, so their forward pass is a few dozen
lines of NumPy on the same safetensors weights, tokenised by the ``tokenizers`` library with the
model's own ``tokenizer.json``. The features match the sentence-transformers ones to float32 rounding
(tests/test_text_encoder.py compares them), so code books made either way are interchangeable.

Only what these checkpoints use is implemented: absolute position embeddings (BERT: from 0; MPNet:
from padding_idx + 1) with MPNet's bucketed relative attention bias, post-LayerNorm blocks, exact
(erf) GELU, and the "mean tokens" pooling of ``1_Pooling/config.json``. Anything else is refused.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.special import erf

from mapping.safe_parse import load_json

__all__ = ["NumpySentenceEncoder"]


class NumpySentenceEncoder:
    """Encode sentences with a sentence-transformers folder, without torch.

    Args:
        folder: a sentence-transformers model folder (``config.json``, ``model.safetensors``,
            ``tokenizer.json``, ``1_Pooling/config.json``, ``sentence_bert_config.json``).

    Raises:
        ValueError: the folder holds another architecture or pooling than BERT / MPNet mean pooling.
        FileNotFoundError: a file the model needs is missing.
    """

    def __init__(self, folder: str | Path):
        from safetensors.numpy import load_file  # noqa: PLC0415 (import cost paid by users only)
        from tokenizers import Tokenizer  # noqa: PLC0415

        folder = Path(folder)
        self.config = load_json(folder / "config.json")
        self.kind = self.config.get("model_type")
        if self.kind not in ("bert", "mpnet") or self.config.get("hidden_act", "gelu") != "gelu":
            raise ValueError(f"{folder}: model_type {self.kind!r} / hidden_act {self.config.get('hidden_act')!r} "
                             "is not supported (BERT or MPNet with GELU only)")
        pooling = load_json(folder / "1_Pooling" / "config.json")
        if not pooling.get("pooling_mode_mean_tokens") or any(
                pooling.get(k) for k in ("pooling_mode_cls_token", "pooling_mode_max_tokens",
                                         "pooling_mode_mean_sqrt_len_tokens")):
            raise ValueError(f"{folder}: only mean-token pooling is supported, got {pooling}")
        st_config = folder / "sentence_bert_config.json"
        max_len = load_json(st_config).get("max_seq_length", 256) if st_config.is_file() else 256
        self.max_seq_length = int(max_len)

        self.tokenizer = Tokenizer.from_file(str(folder / "tokenizer.json"))
        self.tokenizer.no_padding()  # padding is done per batch below
        self.tokenizer.enable_truncation(self.max_seq_length)
        weights = load_file(str(folder / "model.safetensors"))
        self.w = {k.removeprefix(f"{self.kind}."): v for k, v in weights.items()}
        self.heads = int(self.config["num_attention_heads"])
        self.layers = int(self.config["num_hidden_layers"])
        self.eps = float(self.config.get("layer_norm_eps", 1e-12))
        self.pad_id = int(self.config.get("pad_token_id", 0))
        self.dim = int(self.config["hidden_size"])

    def encode(self, texts: Sequence[str], batch_size: int = 64) -> np.ndarray:
        """(len(texts), hidden) float32 unit vectors; sentences of similar length are batched together."""
        encodings = self.tokenizer.encode_batch([str(t) for t in texts])
        out = np.zeros((len(encodings), self.dim), np.float32)
        order = np.argsort([len(e.ids) for e in encodings], kind="stable")
        for start in range(0, len(order), batch_size):
            rows = order[start:start + batch_size]
            width = max(len(encodings[r].ids) for r in rows)
            ids = np.full((len(rows), width), self.pad_id, np.int64)
            mask = np.zeros((len(rows), width), np.float32)
            for k, r in enumerate(rows):
                n = len(encodings[r].ids)
                ids[k, :n], mask[k, :n] = encodings[r].ids, 1.0
            hidden = self._forward(ids, mask)
            pooled = (hidden * mask[..., None]).sum(1) / np.maximum(mask.sum(1, keepdims=True), 1e-9)
            out[rows] = pooled / np.maximum(np.linalg.norm(pooled, axis=1, keepdims=True), 1e-12)
        return out

    # --- the transformer ------------------------------------------------------------------------

    def _forward(self, ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Last hidden states (batch, tokens, hidden) for token ids (batch, tokens) and their 0/1 mask."""
        w = self.w
        if self.kind == "mpnet":  # positions count real tokens from padding_idx + 1 (fairseq)
            positions = (np.cumsum(ids != self.pad_id, axis=1) * (ids != self.pad_id) + self.pad_id).astype(np.int64)
            x = w["embeddings.word_embeddings.weight"][ids] + w["embeddings.position_embeddings.weight"][positions]
            bias = self._relative_bias(ids.shape[1])  # (heads, tokens, tokens), shared by all layers
        else:
            x = (w["embeddings.word_embeddings.weight"][ids]
                 + w["embeddings.position_embeddings.weight"][np.arange(ids.shape[1])][None]
                 + w["embeddings.token_type_embeddings.weight"][0])
            bias = 0.0
        x = self._layer_norm(x, "embeddings.LayerNorm")
        attn_mask = ((1.0 - mask) * np.finfo(np.float32).min)[:, None, None, :]
        for layer in range(self.layers):
            p = f"encoder.layer.{layer}."
            x = self._layer_norm(x + self._attention(x, p, bias, attn_mask),
                                 p + ("attention.LayerNorm" if self.kind == "mpnet" else "attention.output.LayerNorm"))
            h = self._linear(x, p + "intermediate.dense")
            h = 0.5 * h * (1.0 + erf(h / math.sqrt(2.0)))
            x = self._layer_norm(x + self._linear(h, p + "output.dense"), p + "output.LayerNorm")
        return x

    def _attention(self, x: np.ndarray, prefix: str, bias, attn_mask: np.ndarray) -> np.ndarray:
        names = (("attention.attn.q", "attention.attn.k", "attention.attn.v", "attention.attn.o")
                 if self.kind == "mpnet" else ("attention.self.query", "attention.self.key",
                                               "attention.self.value", "attention.output.dense"))
        b, t, d = x.shape
        hd = d // self.heads
        q, k, v = (self._linear(x, prefix + n).reshape(b, t, self.heads, hd).transpose(0, 2, 1, 3) for n in names[:3])
        scores = q @ k.transpose(0, 1, 3, 2) / np.float32(math.sqrt(hd)) + bias + attn_mask
        scores = np.exp(scores - scores.max(axis=-1, keepdims=True))
        probs = scores / scores.sum(axis=-1, keepdims=True)
        context = (probs @ v).transpose(0, 2, 1, 3).reshape(b, t, d)
        return self._linear(context, prefix + names[3])

    def _relative_bias(self, tokens: int) -> np.ndarray:
        """MPNet's (T5-style, bidirectional) bucketed relative position bias, (heads, tokens, tokens)."""
        buckets_total = int(self.config.get("relative_attention_num_buckets", 32))
        relative = np.arange(tokens)[None, :] - np.arange(tokens)[:, None]  # memory - context
        n = -relative
        half = buckets_total // 2
        bucket = (n < 0).astype(np.int64) * half
        n = np.abs(n)
        max_exact = half // 2
        with np.errstate(divide="ignore"):
            large = max_exact + (np.log(np.maximum(n, 1) / max_exact) / math.log(128 / max_exact)
                                 * (half - max_exact)).astype(np.int64)
        bucket += np.where(n < max_exact, n, np.minimum(large, half - 1))
        return self.w["encoder.relative_attention_bias.weight"][bucket].transpose(2, 0, 1)

    def _linear(self, x: np.ndarray, name: str) -> np.ndarray:
        return x @ self.w[name + ".weight"].T + self.w[name + ".bias"]

    def _layer_norm(self, x: np.ndarray, name: str) -> np.ndarray:
        mean = x.mean(-1, keepdims=True)
        var = ((x - mean) ** 2).mean(-1, keepdims=True)
        return (x - mean) / np.sqrt(var + self.eps) * self.w[name + ".weight"] + self.w[name + ".bias"]
