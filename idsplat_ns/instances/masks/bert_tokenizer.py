"""BERT (uncased) WordPiece tokenisation of the Grounding DINO caption, from a user-given
``vocab.txt`` (the one of ``bert-base-uncased`` that Grounding DINO's text encoder uses), and the
text inputs Grounding DINO's ONNX exports expect (``generate_masks_with_special_tokens`` of the
official implementation: each phrase attends to itself, position IDs restart after every ``.``).
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from idsplat_ns.errors import IDSplatError


class WordPieceTokenizer:
    """Lower-casing, accent-stripping, punctuation-splitting WordPiece tokenizer (BERT uncased)."""

    def __init__(self, vocab_path: Path):
        vocab_path = Path(vocab_path)
        if not vocab_path.is_file():
            raise IDSplatError(f"{vocab_path}: BERT vocab.txt not found; give bert-base-uncased's vocab.txt with --masks.grounded-sam2.tokenizer-vocab")
        tokens = vocab_path.read_text(encoding="utf-8").splitlines()
        self.vocab = {t: i for i, t in enumerate(tokens)}
        for special in ("[CLS]", "[SEP]", "[UNK]"):
            if special not in self.vocab:
                raise IDSplatError(f"{vocab_path}: no {special} token; this is not a BERT vocab.txt")

    @staticmethod
    def _basic_split(text: str) -> list[str]:
        text = unicodedata.normalize("NFD", text.lower())
        text = "".join(c for c in text if unicodedata.category(c) != "Mn")
        words, current = [], []
        for c in text:
            if c.isspace():
                if current:
                    words.append("".join(current))
                    current = []
            elif unicodedata.category(c).startswith("P") or (33 <= ord(c) <= 47) or (58 <= ord(c) <= 64):
                if current:
                    words.append("".join(current))
                    current = []
                words.append(c)
            else:
                current.append(c)
        if current:
            words.append("".join(current))
        return words

    def _wordpiece(self, word: str) -> list[str]:
        pieces, start = [], 0
        while start < len(word):  # greedy longest match first
            end = len(word)
            while end > start:
                piece = word[start:end] if start == 0 else "##" + word[start:end]
                if piece in self.vocab:
                    break
                end -= 1
            if end == start:
                return ["[UNK]"]
            pieces.append(piece)
            start = end
        return pieces

    def tokenize(self, text: str) -> list[str]:
        return [p for w in self._basic_split(text) for p in self._wordpiece(w)]

    def encode(self, text: str) -> list[int]:
        """Token IDs with [CLS] and [SEP]."""
        return [self.vocab["[CLS]"]] + [self.vocab[t] for t in self.tokenize(text)] + [self.vocab["[SEP]"]]


@dataclass
class CaptionInputs:
    """Text inputs of a Grounding DINO export, and which tokens belong to which prompt."""

    input_ids: np.ndarray  # [1, L] int64
    attention_mask: np.ndarray  # [1, L] bool
    position_ids: np.ndarray  # [1, L] int64
    token_type_ids: np.ndarray  # [1, L] int64
    text_token_mask: np.ndarray  # [1, L, L] bool: phrase-wise self-attention
    prompt_tokens: list[np.ndarray]  # per prompt, its token positions


def caption_for(prompts: tuple[str, ...]) -> str:
    """Grounding DINO caption: phrases separated and ended by `` .``."""
    return " . ".join(p.strip().lower() for p in prompts) + " ."


def caption_inputs(tokenizer: WordPieceTokenizer, prompts: tuple[str, ...], max_len: int = 256) -> CaptionInputs:
    """Tokenise the prompts into one caption and build the phrase-wise attention and position IDs."""
    ids: list[int] = [tokenizer.vocab["[CLS]"]]
    prompt_tokens = []
    dot = tokenizer.vocab.get(".")
    if dot is None:
        raise IDSplatError("the BERT vocab has no '.' token; give bert-base-uncased's vocab.txt")
    for p in prompts:
        toks = [tokenizer.vocab[t] for t in tokenizer.tokenize(p)]
        prompt_tokens.append(np.arange(len(ids), len(ids) + len(toks)))
        ids += toks + [dot]
    ids.append(tokenizer.vocab["[SEP]"])
    if len(ids) > max_len:
        raise IDSplatError(f"the prompts need {len(ids)} tokens, more than the detector's {max_len}; use fewer prompts")
    L = len(ids)
    special = {tokenizer.vocab["[CLS]"], tokenizer.vocab["[SEP]"], dot, tokenizer.vocab.get("?", -1)}
    attn = np.eye(L, dtype=bool)
    pos = np.zeros(L, np.int64)
    prev = 0
    for col, tok in enumerate(ids):
        if tok not in special:
            continue
        if 0 < col < L - 1:  # a phrase ends here: its tokens (and the separator) attend to each other
            attn[prev + 1 : col + 1, prev + 1 : col + 1] = True
            pos[prev + 1 : col + 1] = np.arange(col - prev)
        prev = col
    return CaptionInputs(
        input_ids=np.array([ids], np.int64), attention_mask=np.ones((1, L), bool), position_ids=pos[None],
        token_type_ids=np.zeros((1, L), np.int64), text_token_mask=attn[None], prompt_tokens=prompt_tokens,
    )
