"""AUTOSAR E2E Profile 1 and 2 (hil/can/e2e.py): published vectors, real VW MQB frames, the receiver state
machine as keyword tables, hypothesis properties, and fuzzed frames through decode + E2E + SecOC.

Every vector names its source.  The corpus DBC lives outside the repository; RAILHIL_CORPUS points
to it (default ../shared/corpus beside the repository), provenance in its SOURCES.md.
"""

from __future__ import annotations

import os
import random
import time

import cantools
import pytest
from cantools.autosar.end_to_end import compute_profile2_crc
from conftest import CORPUS
from hypothesis import given, settings
from hypothesis import strategies as st

import hil.can.e2e
from hil.can.codec import Codec, FrameError
from hil.can.dbc import load_dbc
from hil.can.e2e import (
    CheckState,
    DataIdMode,
    E2EConfigError,
    P01Config,
    P02Config,
    P11Config,
    PCheckStatus,
    ProtectState,
    Status,
    check,
    counter_flip_collisions,
    crc8_h2f,
    crc8_sae_j1850,
    map_status_to_sm,
    protect,
)
from hil.can.secoc import AUTH_BYTES, Reason, SecOcReceiver, SecOcSender
from hil.errors import RailhilError

COMPILED = not hil.can.e2e.__file__.endswith(".py")      # built by mypyc
VW_MQB_DBC = CORPUS / "opendbc" / "opendbc" / "dbc" / "vw_mqb.dbc"   # commaai/opendbc @ 7343a66d4621


# --- CRC primitives ---------------------------------------------------------------------------------

def test_crc_check_values_of_the_autosar_crc_library():
    # AUTOSAR SWS_CRCLibrary "check" values over the ASCII string "123456789" (also the CRC RevEng
    # catalogue entries CRC-8/SAE-J1850 and CRC-8/AUTOSAR).
    assert crc8_sae_j1850(b"123456789") == 0x4B
    assert crc8_h2f(b"123456789") == 0xDF


def test_crc_chaining_continues_the_register():
    # Crc_CalculateCRC8(.., Start = previous result, IsFirstCall = FALSE) == one call over both parts
    assert crc8_sae_j1850(b"6789", crc8_sae_j1850(b"12345"), first_call=False) == 0x4B
    assert crc8_h2f(b"6789", crc8_h2f(b"12345"), first_call=False) == 0xDF


# --- published Profile 1 vectors --------------------------------------------------------------------
# AUTOSAR PRS_E2EProtocol R20-11 §6.3.5 "E2E Profile 1 Protocol Examples" (DataID 0x123, 8 zero bytes,
# CRC in byte 0, counter at bit offset 8, data-id nibble at offset 12), as reproduced by two independent
# open-source implementations that agree on every byte:
#   torsko/autosar-e2e  e2e/test/P01/E2E_P01Protect_tests.cpp  @ 0ebc646d842149601a7c91828596b57deeec8c7f
#   zariiii9003/autosar-e2e  test/test_p01.py  @ 4289fec75a775e261045c5f0e148d9ea1ba60f6a
P01_EXAMPLES = [
    (DataIdMode.BOTH, "cc00000000000000", "9101000000000000"),
    (DataIdMode.ALT, "ce00000000000000", "0201000000000000"),
    (DataIdMode.LOW, "ce00000000000000", "9301000000000000"),
    (DataIdMode.NIBBLE, "2a10000000000000", "7711000000000000"),
]


@pytest.mark.parametrize(("mode", "first", "second"), P01_EXAMPLES, ids=[m.name for m, *_ in P01_EXAMPLES])
def test_p01_protocol_examples(mode, first, second):
    config = P01Config(data_id=0x123, data_id_mode=mode)
    sender = ProtectState()
    assert protect(config, sender, bytes(8)).hex() == first
    assert protect(config, sender, bytes(8)).hex() == second
    assert sender.counter == 2
    state, status = check(config, CheckState(), bytes.fromhex(first))
    assert status is Status.INITIAL
    assert check(config, state, bytes.fromhex(second))[1] is Status.OK


def test_p01_nibble_example_with_crc_in_the_last_byte():
    # torsko/autosar-e2e E2E_P01Protect_tests.cpp @ 0ebc646d, "ProtocolExample_DATAID_NIBBLE_crcInLastByte":
    # counter offset 0, data-id nibble offset 4, CRC offset 56 -- the same CRCs moved to byte 7.
    config = P01Config(0x123, DataIdMode.NIBBLE, crc_offset=56, counter_offset=0, data_id_nibble_offset=4)
    sender = ProtectState()
    assert protect(config, sender, bytes(8)).hex() == "100000000000002a"
    assert protect(config, sender, bytes(8)).hex() == "1100000000000077"


@pytest.mark.parametrize(("mode", "frame"), [
    # zariiii9003/autosar-e2e test/test_p01.py @ 4289fec7: frames its e2e_p01_check rejects
    (DataIdMode.BOTH, "cc10000000000000"),
    (DataIdMode.ALT, "ce10000000000000"),
    (DataIdMode.LOW, "9311000000000000"),
    (DataIdMode.NIBBLE, "7721000000000000"),   # data-id nibble 2, configured 1
])
def test_p01_published_bad_frames_are_errors(mode, frame):
    assert check(P01Config(0x123, mode), CheckState(), bytes.fromhex(frame))[1] is Status.ERROR


# --- published Profile 2 vectors --------------------------------------------------------------------
# zariiii9003/autosar-e2e test/test_p02.py @ 4289fec75a775e261045c5f0e148d9ea1ba60f6a (its protect
# increments the counter it finds in byte 1, ours the sender state: same frames).

def test_p02_library_vectors():
    assert protect(P02Config((0,) * 16), ProtectState(0), bytes(8)).hex() == "4501000000000000"
    ids = P02Config(tuple(range(16)))
    assert protect(ids, ProtectState(1), bytes(range(8))).hex() == "bc02020304050607"
    assert protect(ids, ProtectState(0), bytes(range(8))).hex() == "6101020304050607"
    assert check(ids, CheckState(), bytes.fromhex("bc02020304050607"))[1] is Status.INITIAL
    assert check(ids, CheckState(), bytes.fromhex("bc01020304050607"))[1] is Status.ERROR


# Real VW MQB frames, 16 per message (every counter value), with CRC-8H2F checksums that opendbc's
# checksum tests verify: opendbc/can/tests/test_checksums.py of sunnypilot/opendbc (fork of
# commaai/opendbc) @ 19bd0a23fa403d47b884a0059886799acda5776f, "Test AUTOSAR E2E Profile 2 CRCs".
# Their per-counter "magic" bytes -- the Profile 2 DataIDList -- come from
# opendbc/car/volkswagen/mqbcan.py VOLKSWAGEN_MQB_MEB_CONSTANTS @ 194f162b717998a20abe41ac333847c47e825006.
MQB_DATA_ID_LISTS = {
    "LWI_01": [0x86] * 16,
    "Airbag_01": [0x40] * 16,
    "LH_EPS_03": [0xF5] * 16,
    "Getriebe_11": [0x3F, 0x69, 0x39, 0xDC, 0x94, 0xF9, 0x14, 0x64,
                    0xD8, 0x6A, 0x34, 0xCE, 0xA2, 0x55, 0xB5, 0x2C],
    "ESP_21": [0xB4, 0xEF, 0xF8, 0x49, 0x1E, 0xE5, 0xC2, 0xC0,
               0x97, 0x19, 0x3C, 0xC9, 0xF1, 0x98, 0xD6, 0x61],
    "ESP_02": [0xAA] * 16,
    "ESP_05": [0x07] * 16,
    "ESP_10": [0xAC] * 16,
    "ACC_10": [0x16] * 16,
    "TSK_06": [0xC4, 0xE2, 0x4F, 0xE4, 0xF8, 0x2F, 0x56, 0x81,
               0x9F, 0xE5, 0x83, 0x44, 0x05, 0x3F, 0x97, 0xDF],
    "Motor_20": [0xE9, 0x65, 0xAE, 0x6B, 0x7B, 0x35, 0xE5, 0x5F,
                 0x4E, 0xC7, 0x86, 0xA2, 0xBB, 0xDD, 0xEB, 0xB4],
    "ACC_06": [0x37, 0x7D, 0xF3, 0xA9, 0x18, 0x46, 0x6D, 0x4D,
               0x3D, 0x71, 0x92, 0x9C, 0xE5, 0x32, 0x10, 0xB9],
    "HCA_01": [0xDA] * 16,
    "GRA_ACC_01": [0x6A, 0x38, 0xB4, 0x27, 0x22, 0xEF, 0xE1, 0xBB,
                   0xF8, 0x80, 0x84, 0x49, 0xC7, 0x9E, 0x1E, 0x2B],
    "ACC_07": [0xF8, 0xE5, 0x97, 0xC9, 0xD6, 0x07, 0x47, 0x21,
               0x66, 0xDD, 0xCF, 0x6F, 0xA1, 0x94, 0x74, 0x63],
    "Motor_EV_01": [0x7F, 0xED, 0x17, 0xC2, 0x7C, 0xEB, 0x44, 0x21,
                    0x01, 0xFA, 0xDB, 0x15, 0x4A, 0x6B, 0x23, 0x05],
    "ESP_33": [0x13, 0x21, 0x9B, 0x6A, 0x9A, 0x62, 0xD4, 0x65,
               0x18, 0xF1, 0xAB, 0x16, 0x32, 0x89, 0xE7, 0x26],
    "ACC_02": [0x0F] * 16,
    "SWA_01": [0x0C] * 16,
    "ACC_04": [0x27] * 16,
    "Klemmen_Status_01": [0xC3] * 16,
    "Licht_Anf_01": [0xC5, 0x39, 0xC7, 0xF9, 0x92, 0xD8, 0x24, 0xCE,
                     0xF1, 0xB5, 0x7A, 0xC4, 0xBC, 0x60, 0xE3, 0xD1],
    "ESP_20": [0xAC, 0xB3, 0xAB, 0xEB, 0x7A, 0xE1, 0x3B, 0xF7,
               0x73, 0xBA, 0x7C, 0x9E, 0x06, 0x5F, 0x02, 0xD9],
}

MQB_FRAMES = {   # message name -> the 16 frames of test_checksums.py, counters 0..15 in order
    "LWI_01": """6b00bd0000000000 ee010a0000000000 d802a90000000000 0303bea212000000 7b04312003000000
                 8b05e28509000000 6306132100000000 6607050000000000 49080d0000000000 5f097e6001000000
                 af0a722000000000 590b1b0000000000 a80c060000000000 bc0d722000000000 f90e0f0000000000
                 600f62c000000000""",
    "Airbag_01": """af000080c000203e 54010080c000201a 54020080c0006000 31030080c00060f2 e0040080c00060cc
                    b3050080c00040de a4060080c0004018 94070080c0002038 2d080080c00060ae c2090080c000001c
                    1f0a0080c000602c 7f0b0080c0000000 030c0080c00040d6 560d0080c0002050 4a0e0080c00020f2
                    e50f0080c00040f6""",
    "LH_EPS_03": """11302e00051c8030 5b318e0305530030 cb32d30605730030 f233280005260030 0b344400055b8030
                    ed35800003340030 f0368800053d8030 9e37440305410030 6838060105188030 8739510005118030
                    8c3a290005ac0030 083bbd00058e0030 d43c190005058030 293d5400055b0030 a13e490103048030
                    e23f0500050a0030""",
    "Getriebe_11": """f8e0bfff5f202020 b0e1bfffc6982180 d2e2bfff5f202020 00e3bfffaa202010 f1e4bfff5f202020
                      c4e5bfff5f202020 dae6bfff5f202020 85e7bfff5f202020 12e8bfff5f202020 45e9bfffaa202010
                      03eabfffcc202010 fcebbfff5f202120 feecbfffad202010 bdedbfffaa202010 67eebfffaa202010
                      36efbfffaa202010""",
    "ESP_21": """66d01f8045050000 87d11f8052050000 cdd21f8050060000 fdd31f8035020000 fad41f8022050000
                 fdd51f8084040000 2ed61f80f0030000 9fd71f8000000000 1ed81f80b3030000 61d91f806d050000
                 44da1f8047020000 86db1f803a020000 39dc1f80cb010000 19dd1f8000000000 8cde1f80ba040000
                 fbdf1f8046000000""",
    "ESP_02": """f2007effa12a4000 d3017d00a20c0200 03027a06a2494200 fd0370fba1de0000 8e047bf7a1d20100
                 0f057dfda1314000 b6067d01a20a4000 e8077efda1124000 74087a01a2400100 e3098100a2b50100
                 ab0a7409a29f4200 f30b8012a2940000 880c7f07a2460000 6f0d7fffa1534000 380e73d6a16a4000
                 490f8512a2f60100""",
    "ESP_05": """9080640000 00e710 f481640000 00e710 9082630000 00e810 a083630000 00e610 e784630000 00e810
                 2e85780400 00ea30 7b86630000 00e610 7187790400 00d030 5088790400 00ea30 8189640000 00e110
                 6a8a680000 04d010 178b6a0400 00e610 c78c630000 00d110 538d640400 00e210 248e630000 00e710
                 3f8f820400 00e630""",
    "ESP_10": """2d00d5989f26250f 24016063 2c5e3b0f 0802b22fee9a290f 7c0317071de58c0f aa04d6e3eb98e80f
                 4e05bbd96543ca0f 590678bd25c6f2ff af07428553bebe0f 2a08a6cd958c120f ce096e176d1b2f0f
                 600ad3e63a8df00f c50bfc695750210f 700cdef39de96bff 620dc41adb617a0f 760e7969e332670f
                 150f51595635b10f""",
    "ACC_10": """9b00004068 0000ff ff01004068 0000ff 5302004068 0000ff 3703004068 0000ff 2404004068 0000ff
                 4005004068 0000ff ec06004068 0000ff 8807004068 0000ff ca08004068 0000ff ae09004068 0000ff
                 020a004068 0000ff 660b004068 0000ff 750c004068 0000ff 110d004068 0000ff bd0e004068 0000ff
                 d90f004068 0000ff""",
    "TSK_06": """c100000200 08ff21 3401000200 08ff21 cc02000200 08ff21 1e03000200 08ff21 4804000200 08ff21
                 4a05000200 08ff21 a506000200 08ff21 a707000200 08ff21 fe08000200 08ff21 a809000200 08ff21
                 730a000200 08ff21 df0b000200 08ff21 050c000200 08ff21 b50d000200 08ff21 de0e000200 08ff21
                 0b0f000200 08ff21""",
    "Motor_20": """b90000c039467efe 853120001a467efe c71200401a467efe 5393000019467efe a43400801a467efe
                   0e55206018467efe 3f0600c0374c7efe 0c07004039467efe 2a0800003a467efe 7f4920801a467efe
                   2f0a00c039467efe 70bb000017467efe 060c000039467efe 4b9d20e0164c7efe 73fe004016467efe
                   af0f2080394c7efe""",
    "ACC_06": """148000fe07000018 9f8100fe07000018 0a8200fe07000028 408300fe07000018 2d8400fe07000028
                 db8500fe07000018 4d8600fe07000028 358700fe07000018 238800fe07000028 4a8900fe07000028
                 e18a00fe07000028 308b00fe07000028 608c00fe07000028 0d8d00fe07000018 8c8e00fe07000018
                 6f8f00fe07000028""",
    "HCA_01": """00300dc005fe0700 3e3154c005fe0700 a732bb4005fe0700 963329c005fe0700 5f34000003fe0700
                 3b35ae4005fe0700 c7367a4005fe0700 6f37764005fe0700 b138000003fe0700 d539000003fe0700
                 ba3a69c005fe0700 653b104005fe0700 493c72c005fe0700 c63ddf4005fe0700 1d3e2cc105fe0700
                 9b3f204005fe0700""",
    "GRA_ACC_01": """8640802a00000000 f441802a00000000 5042802a00000000 0843802a00000000 8844802a00000000
                     2d45802a00000000 3446802a00000000 1147802a00000000 c448802a00000000 cc49802a00000000
                     dc4a802a00000000 794b802a00000000 3c4c802a00000000 684d802a00000000 274e802a00000000
                     0d4f802a00000000""",
    "ACC_07": """ace07f00fe00c0ff a2e17f00fe00c0ff 6be27f00fe00c0ff f2e37f00fe00c0ff d5e47f00fe00c0ff
                 35e57f00fe00c0ff 7fe67f00fe00c0ff 6ce77f00fe00c0ff 05e87f00fe00c0ff 79e97f00fe00c0ff
                 25ea7f00fe00c0ff d1eb7f00fe00c0ff 72ec7f00fe00c0ff 58ed7f00fe00c0ff 82ee7f00fe00c0ff
                 85ef7f00fe00c0ff""",
    "Motor_EV_01": """70801500000000f0 07811500000000f0 7a821500000000f0 26831500000000f0 be841500000000f0
                      5a851500000000f0 fc861500000000f0 9e871500000000f0 af881500000000f0 35891500000000f0
                      c58a1500000000f0 118b1500000000f0 d08c1500000000f0 e88d1500000000f0 f58e1500000000f0
                      008f1500000000f0""",
    "ESP_33": """6400800200000000 1901000000000000 fc02001001000000 8b03800200000000 a404001001000000
                 9705000200000100 d506800200000100 a007800200000100 8908000000000000 e309000000000000
                 0e0a000000000000 900b000000000000 320c001001000000 300d000000000000 c20e001001000000
                 680f800200000000""",
    "ACC_02": """82f03f0040300040 e6f13f0040300040 4af23f0040300040 2ef33f0040300040 3df43f0040300040
                 59f53f0040300040 f5f63f0040300040 91f73f0040300040 d3f83f0040300040 b7f93f0040300040
                 1bfa3f0040300040 7ffb3f0040300040 6cfc3f0040300040 08fd3f0040300040 a4fe3f0040300040
                 c0ff3f0040300040""",
    "SWA_01": """1000100000000000 7401100000000000 d802100000000000 bc03100000000000 af04100000000000
                 cb05100000000000 6706100000000000 0307100000000000 4108100000000000 2509100000000000
                 890a100000000000 ed0b100000000000 fe0c100000000000 9a0d100000000000 360e100000000000
                 520f100000000000""",
    "ACC_04": """ba00000000000010 de01000000000010 7202000000000010 1603000000000010 0504000000000010
                 4405000000000000 e806000000000000 a907000000000010 eb08000000000010 8f09000000000010
                 060a000000000000 470b000000000010 710c000000000000 150d000000000000 b90e000000000000
                 dd0f000000000000""",
    "Klemmen_Status_01": """74000300 c1010300 31020300 84030300 fe040300 4b050300 bb060300 0e070300
                            4f080300 fa090300 0a0a0300 bf0b0300 c50c0300 700d0300 800e0300 350f0300""",
    "Licht_Anf_01": """c800000400000000 9f01000400000000 5e02000400000000 5203000400000000 f204000400000000
                       7905000400000000 e606000400000000 fd07000400000000 f808000400000000 c609000400000000
                       f50a000400000000 1a0b000400000000 650c000400000000 410d000400000000 7f0e000400000000
                       980f000400000000""",
    "ESP_20": """98302b1000002281 c8312b1000002281 9d322b1000002281 1f332b1000002281 6e342b1000002281
                 61352b1000002281 6f362b1000002281 e5372b1000002281 f8382b1000002281 e1392b1000002281
                 aa3a2b1000002281 e63b2b1000002281 ef3c2b1000002281 bb3d2b1000002281 9b3e2b1000002281
                 723f2b1000002281""",
}


def _frames(name: str) -> list[bytes]:
    """The hex groups of MQB_FRAMES[name], regrouped into frames of the message's length (some rows
    above are split in two groups only to keep the lines short)."""
    digits = "".join(MQB_FRAMES[name].split())
    size = 8 if name != "Klemmen_Status_01" else 4
    frames = [bytes.fromhex(digits[i:i + 2 * size]) for i in range(0, len(digits), 2 * size)]
    assert len(frames) == 16 and [f[1] & 0x0F for f in frames] == list(range(16))
    return frames


def _mqb_config(name: str) -> P02Config:
    return P02Config(tuple(MQB_DATA_ID_LISTS[name]), length=len(_frames(name)[0]), name=name)


@pytest.mark.parametrize("name", sorted(MQB_FRAMES))
def test_vw_mqb_frames_are_profile_2(name):
    """Each real frame checks, and the 16 in counter order run INITIAL then OK; re-protecting the
    frame's content with the sender at the preceding counter reproduces the frame byte for byte."""
    config = _mqb_config(name)
    state = CheckState()
    for counter, frame in enumerate(_frames(name)):
        assert protect(config, ProtectState((counter - 1) % 16), bytes(1) + frame[1:]) == frame
        state, status = check(config, state, frame)
        assert status is (Status.INITIAL if counter == 0 else Status.OK), (name, counter)


@pytest.mark.parametrize("name", sorted(MQB_FRAMES))
def test_vw_mqb_frames_agree_with_the_corpus_dbc(name):
    """The corpus's opendbc vw_mqb.dbc puts CHECKSUM in byte 0 and the counter in the low nibble of
    byte 1 -- the Profile 2 layout; cantools decodes the same CRC and counter from each real frame."""
    if not VW_MQB_DBC.is_file():
        pytest.skip(f"corpus file {VW_MQB_DBC} not present")
    db = _vw_mqb_db()
    message = db.get_message_by_name(name)
    counter_signal = "COUNTER_DISABLED" if name == "Getriebe_11" else "COUNTER"   # see opendbc#1235
    for frame in _frames(name):
        decoded = message.decode(frame, decode_choices=False)
        assert decoded["CHECKSUM"] == frame[0]
        assert decoded[counter_signal] == frame[1] & 0x0F


_VW_DB: list = []


def _vw_mqb_db():
    if not _VW_DB:   # vw_mqb.dbc has overlapping signals elsewhere (PLA_01): cantools needs strict=False
        _VW_DB.append(cantools.database.load_file(str(VW_MQB_DBC), strict=False))
    return _VW_DB[0]


def test_vw_mqb_lists_let_no_counter_bit_flip_through():
    for name in MQB_FRAMES:
        assert counter_flip_collisions(_mqb_config(name)) == (), name


# --- our DBC's layout -------------------------------------------------------------------------------

def test_default_p01_offsets_are_the_train_brake_dbc_fields():
    """P01Config's defaults put the CRC and counter where dbc/train_brake.dbc's CHECKSUM and COUNTER
    are: cantools decodes the values protect() wrote, for every message that has both."""
    db = load_dbc()
    protected = [m for m in db.messages if {"CHECKSUM", "COUNTER"} <= {s.name for s in m.signals}]
    assert protected
    rng = random.Random(9)
    for message in protected:
        config = P01Config(data_id=message.frame_id, length=message.length, name=message.name)
        sender = ProtectState(counter=rng.randrange(15))
        sent_counter = sender.counter
        payload = protect(config, sender, bytes(rng.randrange(256) for _ in range(message.length)))
        decoded = message.decode(payload, decode_choices=False)
        assert decoded["COUNTER"] == sent_counter
        assert decoded["CHECKSUM"] == payload[0]
        assert check(config, CheckState(), payload)[1] is Status.INITIAL


# --- receiver state machine: keyword tables ---------------------------------------------------------

def _frame(config, counter: int, payload: bytes = bytes(8)) -> bytes:
    """The frame a sender emits with ``counter`` (P02 increments before writing)."""
    start = counter if isinstance(config, P01Config) else (counter - 1) % 16
    return protect(config, ProtectState(start), payload)


def _run(config, steps):
    """Feed ``steps`` (counter, ``None`` for no data, or ``("corrupt", counter)``) and collect the
    statuses and the last state."""
    state, statuses = CheckState(), []
    for step in steps:
        if step is None:
            frame = None
        elif isinstance(step, tuple):
            frame = bytearray(_frame(config, step[1], bytes(range(8))))
            frame[5] ^= 0x10
            frame = bytes(frame)
        else:
            frame = _frame(config, step, bytes(range(8)))
        state, status = check(config, state, frame)
        statuses.append(status)
    return statuses, state


S = Status
PROFILES = {"P01": P01Config(data_id=0x28), "P02": P02Config(tuple(range(0x50, 0x60)))}
SEQUENCE_TABLE = [
    # name, steps, expected statuses (last one checked in detail where it matters)
    ("first frame", [3], [S.INITIAL]),
    ("consecutive", [3, 4, 5], [S.INITIAL, S.OK, S.OK]),
    ("repeated frame", [3, 4, 4], [S.INITIAL, S.OK, S.REPEATED]),
    ("one lost", [3, 4, 6], [S.INITIAL, S.OK, S.OKSOMELOST]),
    ("two lost, more than MaxDeltaCounter", [3, 4, 7], [S.INITIAL, S.OK, S.WRONGSEQUENCE]),
    ("no new data", [3, None], [S.INITIAL, S.NONEWDATA]),
    ("a silent cycle widens the window", [3, None, 6], [S.INITIAL, S.NONEWDATA, S.OKSOMELOST]),
    ("corrupted byte", [3, ("corrupt", 4)], [S.INITIAL, S.ERROR]),
    ("after an error the next frame is fine", [3, ("corrupt", 4), 5], [S.INITIAL, S.ERROR, S.OKSOMELOST]),
    ("error before the first frame", [("corrupt", 3), 4], [S.ERROR, S.INITIAL]),
    ("stale frame after wrong sequence", [3, 9, 4], [S.INITIAL, S.WRONGSEQUENCE, S.OK]),
]


@pytest.mark.parametrize("profile", sorted(PROFILES))
@pytest.mark.parametrize(("name", "steps", "expected"), SEQUENCE_TABLE, ids=[r[0] for r in SEQUENCE_TABLE])
def test_sequence_table(profile, name, steps, expected):
    statuses, _ = _run(PROFILES[profile], steps)
    assert statuses == expected


@pytest.mark.parametrize(("profile", "last"), [("P01", 14), ("P02", 15)])
def test_counter_wraps(profile, last):
    statuses, state = _run(PROFILES[profile], [last - 1, last, 0, 1])
    assert statuses == [S.INITIAL, S.OK, S.OK, S.OK]
    assert state.last_valid_counter == 1


def test_p01_counter_15_is_an_error_even_with_a_right_crc():
    config = P01Config(data_id=0x28)
    frame = bytearray(8)
    frame[1] = 0x0F
    frame[0] = crc8_sae_j1850(bytes((0x28, 0x00)) + bytes(frame[1:]), 0xFF, first_call=False) ^ 0xFF
    assert check(config, CheckState(), bytes(frame))[1] is Status.ERROR
    frame[1] = 0x0E   # the same formula is the CRC protect() writes
    frame[0] = crc8_sae_j1850(bytes((0x28, 0x00)) + bytes(frame[1:]), 0xFF, first_call=False) ^ 0xFF
    assert bytes(frame) == protect(config, ProtectState(14), bytes(8))


def test_lost_data_counts_the_frames_lost():
    _, state = _run(PROFILES["P02"], [3, 4, 6])
    assert state.lost_data == 1
    _, state = _run(PROFILES["P02"], [3, None, None, 7])
    assert state.lost_data == 3


def test_sync_counter_after_wrong_sequence():
    """With SyncCounterInit 2, a wrong sequence re-anchors the counter and the next 2 frames are SYNC."""
    config = P01Config(data_id=0x28, sync_counter_init=2)
    statuses, _ = _run(config, [3, 4, 9, 10, 11, 12])
    assert statuses == [S.INITIAL, S.OK, S.WRONGSEQUENCE, S.SYNC, S.SYNC, S.OK]


def test_resync_after_a_timeout():
    """More silent cycles than MaxNoNewOrRepeatedData: the next consecutive frame is SYNC."""
    config = P02Config(tuple(range(16)), max_no_new_or_repeated_data=2, max_delta_counter_init=3)
    statuses, state = _run(config, [3, None, None, None, 4, 5])
    assert statuses == [S.INITIAL, S.NONEWDATA, S.NONEWDATA, S.NONEWDATA, S.SYNC, S.OK]
    assert state.no_new_or_repeated_data_counter == 0


def test_no_new_data_counter_saturates_at_14():
    statuses, state = _run(PROFILES["P01"], [3] + [None] * 20)
    assert statuses[-1] is S.NONEWDATA
    assert state.no_new_or_repeated_data_counter == 14
    assert state.max_delta_counter == 14


@pytest.mark.parametrize(("payload", "why"), [(b"", "empty"), (bytes(7), "short"), (bytes(9), "long")])
def test_wrong_length_is_an_error(payload, why):
    for config in PROFILES.values():
        assert check(config, CheckState(), payload)[1] is Status.ERROR, why


def test_status_usable_follows_the_sm_mapping():
    assert {s for s in Status if s.usable} == {S.OK, S.OKSOMELOST, S.SYNC}
    assert map_status_to_sm(S.INITIAL) is PCheckStatus.WRONGSEQUENCE
    assert map_status_to_sm(S.INITIAL, profile_behavior=False) is PCheckStatus.OK
    assert map_status_to_sm(S.SYNC, profile_behavior=False) is PCheckStatus.WRONGSEQUENCE
    assert map_status_to_sm(S.ERROR) is PCheckStatus.ERROR


def test_check_is_pure():
    config, state = PROFILES["P01"], CheckState()
    frame = _frame(config, 3)
    first = check(config, state, frame)
    assert check(config, state, frame) == first
    assert state == CheckState()


# --- configuration errors: one line, a RailhilError ---------------------------------------------------

@pytest.mark.parametrize(("build", "words"), [
    (lambda: P01Config(data_id=0x10000), "data_id"),
    (lambda: P01Config(data_id=0x1123, data_id_mode=DataIdMode.NIBBLE), "12 bits"),
    (lambda: P01Config(data_id=1, length=31), "length"),
    (lambda: P01Config(data_id=1, crc_offset=4), "crc_offset"),
    (lambda: P01Config(data_id=1, counter_offset=2), "counter_offset"),
    (lambda: P01Config(data_id=1, counter_offset=4), "CRC byte"),
    (lambda: P01Config(data_id=1, max_delta_counter_init=0), "max_delta_counter_init"),
    (lambda: P01Config(data_id=1, data_id_mode=DataIdMode.NIBBLE, data_id_nibble_offset=8), "overlaps"),
    (lambda: P02Config((0,) * 15), "16 data id bytes"),
    (lambda: P02Config((0,) * 15 + (256,)), "data_id_list[15]"),
    (lambda: P02Config((0,) * 16, length=1), "length"),
    (lambda: protect(P01Config(data_id=1), ProtectState(), bytes(7)), "payload of 7 bytes"),
    (lambda: protect(P01Config(data_id=1), ProtectState(15), bytes(8)), "sender counter"),
])
def test_config_errors_are_one_line(build, words):
    with pytest.raises(E2EConfigError) as info:
        build()
    assert isinstance(info.value, RailhilError) and info.value.exit_code == 2
    assert words in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(("build", "words"), [
    (lambda: P01Config(data_id=1, data_id_mode="BOTH"), "data_id_mode"),
    (lambda: P01Config(data_id=1.0), "data_id = 1.0"),
    (lambda: P02Config([0] * 16), "data_id_list = [0,"),
    (lambda: P02Config(bytes(16)), "16 data id bytes"),
    (lambda: P11Config(1, "BOTH"), "data_id_mode = 'BOTH'"),
])
def test_a_value_of_the_wrong_type_is_a_type_error(build, words):
    """A programming error, not a configuration's: compiled, the fields' types refuse it (mypyc checks a
    native class's fields when they are set, in its own words); interpreted, the module's own checks, in
    words that name it."""
    with pytest.raises(TypeError) as info:
        build()
    assert COMPILED or words in str(info.value)


# --- properties -------------------------------------------------------------------------------------

p01_configs = st.builds(
    lambda mode, data_id, length: P01Config(data_id & (0x0FFF if mode is DataIdMode.NIBBLE else 0xFFFF),
                                            mode, length=length),
    st.sampled_from(DataIdMode), st.integers(0, 0xFFFF), st.integers(2, 30))
p02_configs = st.builds(lambda ids, length: P02Config(tuple(ids), length=length),
                        st.lists(st.integers(0, 255), min_size=16, max_size=16), st.integers(2, 64))
configs = st.one_of(p01_configs, p02_configs)


@given(configs, st.data())
@settings(max_examples=60, deadline=None)
def test_protect_then_check_round_trips(config, data):
    """Any payloads, sent in order across counter wraps: INITIAL, then OK every time."""
    sender, state = ProtectState(data.draw(st.integers(0, 14))), CheckState()
    for i in range(20):
        payload = data.draw(st.binary(min_size=config.length, max_size=config.length))
        frame = protect(config, sender, payload)
        assert frame[2:] == payload[2:]                  # only the CRC and counter bytes change
        state, status = check(config, state, frame)
        assert status is (Status.INITIAL if i == 0 else Status.OK)


def _bits_outside(config) -> list[int]:
    """Bit positions whose single flip a CRC-8 must detect for this configuration: all, except the
    counter nibble in P02 (it also selects the data id) and the counter LSB in P01 ALT mode (it
    selects which data id byte enters the CRC)."""
    bits = range(config.length * 8)
    if isinstance(config, P02Config):
        return [b for b in bits if not 8 <= b < 12]
    if config.data_id_mode is DataIdMode.ALT:
        return [b for b in bits if b != config.counter_offset]
    return list(bits)


@given(configs, st.data())
@settings(max_examples=80, deadline=None)
def test_any_single_bit_flip_is_an_error(config, data):
    payload = data.draw(st.binary(min_size=config.length, max_size=config.length))
    frame = protect(config, ProtectState(data.draw(st.integers(0, 14))), payload)
    for bit in _bits_outside(config):
        flipped = bytearray(frame)
        flipped[bit // 8] ^= 1 << (bit % 8)
        assert check(config, CheckState(), bytes(flipped))[1] is Status.ERROR, bit


@given(p02_configs, st.integers(0, 15))
@settings(max_examples=80, deadline=None)
def test_p02_counter_flips_pass_exactly_where_the_list_collides(config, counter):
    """A counter-nibble flip passes the CRC iff counter_flip_collisions lists it."""
    frame = _frame(config, counter, bytes(config.length))
    collisions = set(counter_flip_collisions(config))
    for bit in range(4):
        flipped = bytearray(frame)
        flipped[1] ^= 1 << bit
        passed = check(config, CheckState(), bytes(flipped))[1] is not Status.ERROR
        assert passed == ((counter, bit) in collisions)


@given(st.binary(min_size=2, max_size=64), st.lists(st.integers(0, 255), min_size=16, max_size=16))
@settings(max_examples=100, deadline=None)
def test_p02_crc_equals_cantools(payload, ids):
    """cantools' own AUTOSAR E2E profile 2 CRC (cantools.autosar.end_to_end) agrees on any payload."""
    config = P02Config(tuple(ids), length=len(payload))
    expected = compute_profile2_crc(payload, ids[payload[1] & 0x0F])
    state, status = check(config, CheckState(), bytes((expected,)) + payload[1:])
    assert status is Status.INITIAL


@given(configs, st.lists(st.one_of(st.none(), st.binary(max_size=70)), max_size=30))
@settings(max_examples=100, deadline=None)
def test_check_never_raises_on_received_data(config, frames):
    state = CheckState()
    for frame in frames:
        state, status = check(config, state, frame)
        assert isinstance(status, Status)
        assert 0 <= state.max_delta_counter <= 15 and 0 <= state.no_new_or_repeated_data_counter <= 14


# --- fuzzed frames through decode + E2E + SecOC -------------------------------------------------------

def fuzz_frames(count: int, seed: int) -> dict[str, int]:
    """Push ``count`` frames -- genuine, replayed, bit-flipped, truncated, extended, random -- for every
    E2E-protected message of dbc/train_brake.dbc through SecOC verify, E2E check and the DBC decode.

    Each message is E2E Profile 1 protected (data id = frame id) and SecOC secured (a 12-byte
    secured frame: 8-byte payload + 4 authentication bytes).  Only ``FrameError`` (the codec's typed
    error for a payload it cannot decode) may come out of the decode; verify and check never raise.
    """
    rng = random.Random(seed)
    db = load_dbc()
    codec = Codec(db)
    messages = [m for m in db.messages if {"CHECKSUM", "COUNTER"} <= {s.name for s in m.signals}]
    links = {}
    for m in messages:
        key = rng.randbytes(16)
        config = P01Config(data_id=m.frame_id, length=m.length, name=m.name)
        links[m.frame_id] = dict(config=config, sender=ProtectState(), secoc_tx=SecOcSender(key, m.frame_id),
                                 secoc_rx=SecOcReceiver(key, m.frame_id), state=CheckState(),
                                 sent={}, history=[], codec=codec[m.frame_id])
    tally = dict.fromkeys(["frames", "secoc_accepted", "secoc_rejected", "e2e_usable", "decoded",
                           "decode_errors", "forged"], 0)
    ids = list(links)
    for _ in range(count):
        link = links[rng.choice(ids)]
        kind = rng.random()
        if kind < 0.45 or not link["history"]:
            payload = protect(link["config"], link["sender"], rng.randbytes(link["config"].length))
            frame = link["secoc_tx"].secure(payload)
            link["sent"][link["secoc_tx"].freshness] = payload
            link["history"].append(frame)
            del link["history"][:-32]
        elif kind < 0.60:
            frame = rng.choice(link["history"])                                  # replay
        elif kind < 0.80:
            frame = bytearray(rng.choice(link["history"]))                       # 1..3 bit flips
            for _ in range(rng.randint(1, 3)):
                bit = rng.randrange(len(frame) * 8)
                frame[bit // 8] ^= 1 << (bit % 8)
            frame = bytes(frame)
        elif kind < 0.90:
            base = rng.choice(link["history"])                                   # truncate or extend
            frame = base[:rng.randrange(len(base))] if rng.random() < 0.5 else base + rng.randbytes(4)
        else:
            frame = rng.randbytes(rng.randrange(17))                             # garbage
        tally["frames"] += 1
        verdict = link["secoc_rx"].verify(frame)
        if verdict.accepted:
            tally["secoc_accepted"] += 1
            if link["sent"].get(verdict.freshness) != verdict.payload:
                tally["forged"] += 1
        else:
            tally["secoc_rejected"] += 1
        link["state"], status = check(link["config"], link["state"], verdict.payload)
        tally["e2e_usable"] += status.usable
        try:
            link["codec"].decode(frame[:max(0, len(frame) - AUTH_BYTES)])
            tally["decoded"] += 1
        except FrameError:
            tally["decode_errors"] += 1
    assert sum(link["secoc_rx"].counts[Reason.ACCEPTED] for link in links.values()) == tally["secoc_accepted"]
    return tally


def test_fuzzed_frames_small():
    tally = fuzz_frames(20_000, seed=1)
    assert tally["frames"] == 20_000 == tally["secoc_accepted"] + tally["secoc_rejected"]
    assert tally["secoc_accepted"] > 5_000 and tally["e2e_usable"] > 5_000
    assert tally["decoded"] > 0 and tally["decode_errors"] > 0
    assert tally["forged"] == 0


@pytest.mark.slow
def test_a_million_fuzzed_frames():
    count = int(os.environ.get("RAILHIL_FUZZ_FRAMES", 1_000_000))
    start = time.perf_counter()
    tally = fuzz_frames(count, seed=int(os.environ.get("RAILHIL_FUZZ_SEED", 2)))
    elapsed = time.perf_counter() - start
    print(f"\n{tally['frames']} fuzzed frames through SecOC verify + E2E check + decode in {elapsed:.1f} s "
          f"({tally['frames'] / elapsed:,.0f} frames/s): {tally}")
    assert tally["frames"] == count == tally["secoc_accepted"] + tally["secoc_rejected"]
    # A 24-bit MAC lets a random frame through with probability 2**-24 per MAC check; fewer than
    # 10**6 checks are made here, so more than one forged frame would mean a broken verifier.
    assert tally["forged"] <= 1
