"""The Grounding DINO caption tokenizer against transformers' pure-Python BERT tokenizer (the port of
Google's original basic + WordPiece steps), on the project's captions and on adversarial text."""

from __future__ import annotations

import string

import numpy as np
import pytest
from transformers.models.bert.tokenization_bert_legacy import BasicTokenizer, WordpieceTokenizer, load_vocab

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.masks.base import PROMPT_CLASSES
from idsplat_ns.instances.masks.bert_tokenizer import WordPieceTokenizer, caption_for, caption_inputs

WORDS = ["car", "truck", "van", "bus", "train", "human", "cycl", "##ist", "bicycle", "pedestrian", "bi", "##cycle", "##s",
         "##es", "##ing", "park", "##ed", "tr", "##uck", "cafe", "naive", "person", "motor", "traffic", "ß", "##ß", "中", "国"]
VOCAB = (["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]"] + list(string.punctuation) + list(string.ascii_lowercase + string.digits)
         + ["##" + c for c in string.ascii_lowercase + string.digits] + WORDS)

ADVERSARIAL = [
    caption_for(PROMPT_CLASSES), "Cyclist . Truck!", "CAFÉ naïve Über", "e\u0301te",  # accents, precomposed or not
    "bicycles, parked-cars; (trucks)", "a^b`c|d~e", "don't", "car.truck", "...", "", "   ",
    "x" * 150, "pedestrian" * 12,  # words over 100 characters are [UNK]
    "中国car", "emoji 🚗 car", "ẞtraße", "İstanbul", "ΣΟΦΟΣ",  # CJK split apart, unknown symbols, special casing
    "tab\tnew\nline\rcr", "zero\u200bwidth", "ctrl\x1cchar", "\x00nul\ufffd", "non\u00a0break\u3000ideographic",
]


@pytest.fixture(scope="module")
def tokenizers(tmp_path_factory):
    path = tmp_path_factory.mktemp("bert") / "vocab.txt"
    path.write_text("\n".join(VOCAB) + "\n", encoding="utf-8")
    basic, wordpiece = BasicTokenizer(do_lower_case=True, tokenize_chinese_chars=True), WordpieceTokenizer(load_vocab(str(path)), "[UNK]")
    return WordPieceTokenizer(path), lambda text: [p for w in basic.tokenize(text) for p in wordpiece.tokenize(w)]


def test_tokens_match_the_reference_bert_on_adversarial_text(tokenizers):
    ours, reference = tokenizers
    for text in ADVERSARIAL:
        assert ours.tokenize(text) == reference(text), repr(text)
    assert ours.tokenize("a^b`c|d~e") == ["a", "^", "b", "`", "c", "|", "d", "~", "e"]  # symbols BERT counts as punctuation
    assert ours.tokenize("x" * 150) == ["[UNK]"]


def test_tokens_match_the_reference_bert_on_random_text(tokenizers):
    ours, reference = tokenizers
    rng = np.random.default_rng(0)
    alphabet = list(string.ascii_letters + string.digits + string.punctuation + " \t\n") + list("éüßÅçñ中国🚗\u0301\u00a0\u3000\x1c")
    for _ in range(300):
        text = "".join(rng.choice(alphabet, rng.integers(1, 80)))
        assert ours.tokenize(text) == reference(text), repr(text)


def test_caption_inputs_of_the_project_prompts(tokenizers):
    ours, reference = tokenizers
    vocab = {t: i for i, t in enumerate(VOCAB)}
    cap = caption_inputs(ours, PROMPT_CLASSES)
    expected = [vocab[t] for t in ["[CLS]"] + reference(caption_for(PROMPT_CLASSES)) + ["[SEP]"]]
    np.testing.assert_array_equal(cap.input_ids[0], expected)
    assert ours.encode(caption_for(PROMPT_CLASSES)) == expected
    dots = np.flatnonzero(cap.input_ids[0] == vocab["."])
    assert len(dots) == len(PROMPT_CLASSES)
    # Each phrase (with its dot) attends only to itself; positions restart after every dot.
    starts = np.concatenate([[1], dots[:-1] + 1])
    for p, (a, b) in enumerate(zip(starts, dots)):
        np.testing.assert_array_equal(cap.prompt_tokens[p], np.arange(a, b))
        np.testing.assert_array_equal(cap.position_ids[0, a : b + 1], np.arange(b + 1 - a))
        block = cap.text_token_mask[0, a : b + 1]
        assert block[:, a : b + 1].all() and block.sum() == (b + 1 - a) ** 2


def test_vocab_errors_name_the_file(tmp_path):
    with pytest.raises(IDSplatError, match="nowhere.txt.*tokenizer-vocab"):
        WordPieceTokenizer(tmp_path / "nowhere.txt")
    no_cls = tmp_path / "no_cls.txt"
    no_cls.write_text("[PAD]\n[UNK]\n[SEP]\ncar\n")
    with pytest.raises(IDSplatError, match=r"no_cls.txt: no \[CLS\]"):
        WordPieceTokenizer(no_cls)
    binary = tmp_path / "binary.txt"
    binary.write_bytes(b"[CLS]\n\xff\xfe\x00\x81\n")
    with pytest.raises(IDSplatError, match="binary.txt: not a readable BERT vocab"):
        WordPieceTokenizer(binary)
