"""BERT (uncased) WordPiece tokenisation of the Grounding DINO caption, from a user-given
``vocab.txt`` (the one of ``bert-base-uncased`` that Grounding DINO's text encoder uses), and the
text inputs Grounding DINO's ONNX exports expect (``generate_masks_with_special_tokens`` of the
official implementation: each phrase attends to itself, position IDs restart after every ``.``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tokenizers import Tokenizer, normalizers, pre_tokenizers
from tokenizers.models import WordPiece

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.options import cli_option


class WordPieceTokenizer:
    """BERT uncased tokenisation by the ``tokenizers`` library: text cleaning, lower-casing, accent
    stripping, CJK characters and punctuation split apart, greedy longest-match WordPiece (words
    over 100 characters are ``[UNK]``), as ``bert-base-uncased``'s own tokenizer does."""

    def __init__(self, vocab_path: Path):
        vocab_path = Path(vocab_path)
        if not vocab_path.is_file():
            raise IDSplatError(f"{vocab_path}: BERT vocab.txt not found; give bert-base-uncased's vocab.txt with {cli_option('masks.grounded-sam2.tokenizer-vocab')}")
        try:
            self.vocab: dict[str, int] = WordPiece.read_file(str(vocab_path))  # token -> ID (its line)
        except Exception as exc:  # the binding raises a bare Exception (unreadable, not UTF-8)
            raise IDSplatError(f"{vocab_path}: not a readable BERT vocab.txt ({exc}); give bert-base-uncased's vocab.txt") from None
        for special in ("[CLS]", "[SEP]", "[UNK]"):
            if special not in self.vocab:
                raise IDSplatError(f"{vocab_path}: no {special} token; this is not a BERT vocab.txt")
        self._tokenizer = Tokenizer(WordPiece(self.vocab, unk_token="[UNK]", max_input_chars_per_word=100))
        self._tokenizer.normalizer = normalizers.BertNormalizer(
            clean_text=True, handle_chinese_chars=True, strip_accents=None, lowercase=True)  # None: strip with lowercase
        self._tokenizer.pre_tokenizer = pre_tokenizers.BertPreTokenizer()

    def tokenize(self, text: str) -> list[str]:
        """WordPiece tokens of ``text`` (no [CLS]/[SEP])."""
        return self._tokenizer.encode(text, add_special_tokens=False).tokens

    def encode(self, text: str) -> list[int]:
        """Token IDs with [CLS] and [SEP]."""
        ids = self._tokenizer.encode(text, add_special_tokens=False).ids
        return [self.vocab["[CLS]"]] + ids + [self.vocab["[SEP]"]]


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
