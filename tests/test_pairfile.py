"""Pair files: one loader for YAML and JSON, exact round trip, one-line validation messages naming the key."""

import json

import numpy as np
import pytest

from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.cameras import PairGeometry, kitti_pair, middlebury_pair
from riverbed_cli.geometry.pairfile import load_pairfile, load_registration, write_pairfile

PL = [[935.0, 0.0, 224.5, 0.0], [0.0, 935.0, 187.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
PR = [[935.0, 0.0, 249.5, -149.6], [0.0, 935.0, 187.0, 0.0], [0.0, 0.0, 1.0, 0.0]]


def text(**changes):
    data = {"left": "im2.png", "right": "im6.png", "P_left": PL, "P_right": PR}
    data.update(changes)
    return "".join(f"{k}: {json.dumps(v)}\n" for k, v in data.items() if v is not None)


def load(tmp_path, content, name="pair.yaml"):
    path = tmp_path / name
    path.write_text(content)
    return load_pairfile(path)


def test_yaml_and_json_load_alike(tmp_path):
    a = load(tmp_path, text(origin=[500000.0, 5000000.0, 300.0], crs="EPSG:32632"))
    data = {"left": "im2.png", "right": "im6.png", "P_left": PL, "P_right": PR,
            "origin": [500000, 5000000, 300], "crs": "EPSG:32632"}
    b = load(tmp_path, json.dumps(data), "pair.json")
    for key in ("P_left", "P_right", "origin", "registration"):
        assert np.array_equal(getattr(a, key), getattr(b, key))
    assert a.left == b.left == (tmp_path / "im2.png").absolute()
    assert a.crs == "EPSG:32632" and np.array_equal(a.registration, np.eye(4))
    assert a.baseline == pytest.approx(0.16) and a.focal == 935.0 and a.exactly_rectified
    # YAML 1.1 reads 1e-3 as a string: accepted as the number it spells.
    c = load(tmp_path, "P_left: [[935, 0, 224.5, 0], [0, 935, 187, 0], [0, 0, 1, 0]]\n"
                       "P_right: [[935, 0, 249.5, -1.496e+2], [0, 935, 187, 0], [0, 0, 1, 0]]\ncrs: 2154\n")
    assert c.P_right[0, 3] == -149.6 and c.crs == "EPSG:2154" and c.left is None


def test_write_read_exact_and_relative_paths(tmp_path):
    rng = np.random.default_rng(1)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = rng.normal(size=3) * 10
    pair = PairGeometry(np.array(PL) @ T, np.array(PR) @ T, origin=[500000.123, 5000000.456, 300.789],
                        registration=T, crs="EPSG:32632", left=tmp_path / "img" / "l.png",
                        right=tmp_path / "img" / "r.png", width=450, height=375)
    (tmp_path / "sub").mkdir()
    for name in ("sub/pair.yaml", "sub/pair.json"):
        write_pairfile(tmp_path / name, pair)
        back = load_pairfile(tmp_path / name)
        for key in ("P_left", "P_right", "origin", "registration"):
            assert np.array_equal(getattr(back, key), getattr(pair, key)), key  # bit-exact floats
        assert back.left == (tmp_path / "img" / "l.png").absolute() and back.image_size == (375, 450)
        assert back.disparity is None
    ranged = pair.replace(disparity=[12, 57.5])
    write_pairfile(tmp_path / "sub/ranged.yaml", ranged)
    assert load_pairfile(tmp_path / "sub/ranged.yaml").disparity == (12.0, 57.5)
    assert "left: ../img/l.png" in (tmp_path / "sub/pair.yaml").read_text()
    with pytest.raises(RiverbedError, match="output exists"):
        write_pairfile(tmp_path / "sub/pair.yaml", pair)


def _bad(**changes):
    return text(**changes)


RECT = ("a rectified pair differs only by a horizontal shift (equal rows 1 and 2, row 0 may add a multiple "
        "of row 2, 4th column free)")
CASES = {
    "not a mapping": ("- 1\n- 2\n", "not a pair file (expected a mapping with P_left and P_right)"),
    "unknown key": (_bad(P_lft=PL), ("unknown key 'P_lft' (pair file keys: left, right, width, height, "
                                     "P_left, P_right, origin, crs, registration, disparity)")),
    "missing": (_bad(P_right=None), "P_right: missing (a 3x4 projection matrix)"),
    "rows": (_bad(P_left=PL[:2]), "P_left: expected a 3x4 matrix, got 2 rows"),
    "row length": (_bad(P_right=[PR[0], PR[1][:3], PR[2]]),
                   "P_right: expected a 3x4 matrix, row 2 has 3 numbers"),
    "not a list": (_bad(P_left="identity"), "P_left: expected a 3x4 matrix, got str"),
    "not a number": (_bad(P_left=[PL[0], [0, "f", 187, 0], PL[2]]),
                     "P_left: entry [1][1] is not a number: 'f'"),
    "bool": (_bad(P_left=[PL[0], PL[1], [0, 0, True, 0]]), "P_left: entry [2][2] is not a number: True"),
    "nan": ("P_left: [[935, 0, 224.5, .nan], [0, 935, 187, 0], [0, 0, 1, 0]]\nP_right: " + json.dumps(PR),
            "P_left: entry [0][3] is not finite: nan"),
    "not rectified": (_bad(P_right=[PR[0], [0, 935, 190.0, 0], [0.001, 0, 1, 0]]),
                      ("P_left and P_right are not a rectified pair: they differ at [1][2] (187 vs 190), "
                       f"[2][0] (0 vs 0.001); {RECT}")),
    "focal": (_bad(P_right=[[936.0, 0, 249.5, -149.6], PR[1], PR[2]]),
              f"P_left and P_right are not a rectified pair: they differ at [0][0] (935 vs 936); {RECT}"),
    "swapped": (_bad(P_left=PR, P_right=PL),
                "P_right is to the left of P_left (disparities would be negative): swap left and right"),
    "same": (_bad(P_right=PL), "P_left and P_right have the same camera centre (no baseline)"),
    "vertical": (_bad(P_right=[PR[0], [0, 935, 187, 10.0], PR[2]]),
                 ("P_left and P_right are not a rectified pair: the right camera is off the baseline (4th "
                  "column [1][3] 0 vs 10, [2][3] 0 vs 0): 6.7 % of the horizontal shift, above 5 %")),
    "singular": (_bad(P_left=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]],
                      P_right=[[1, 0, 0, -1], [0, 1, 0, 0], [0, 0, 0, 1]]),
                 "P_left: the left 3x3 block is singular (not a finite camera)"),
    "origin": (_bad(origin=[1, 2]), "origin: expected 3 numbers, got 2 numbers"),
    "registration row": (_bad(registration=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]),
                         "registration: the last row must be 0 0 0 1, got 0 0 1 1"),
    "registration singular": (_bad(registration=[[1, 0, 0, 5], [0, 1, 0, 0], [1, 1, 0, 0], [0, 0, 0, 1]]),
                              "registration: the 3x3 block is singular (not an invertible transform)"),
    "registration shape": (_bad(registration=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
                           "registration: expected a 4x4 matrix, got 3 rows"),
    "width": (_bad(width=-3), "width: expected a positive integer (pixels), got -3"),
    "crs": (_bad(crs=["EPSG", 2154]), "crs: expected a string such as EPSG:32632, got list"),
    "left": (_bad(left=5), "left: expected a file name, got 5"),
    "disparity shape": (_bad(disparity=[1, 2, 3]), "disparity: expected [low, high] in pixels, got [1, 2, 3]"),
    "disparity order": (_bad(disparity=[50, 10]),
                        "disparity: expected finite [low, high] with low <= high, got [50, 10]"),
    "disparity text": (_bad(disparity="wide"), "disparity: expected [low, high] in pixels, got 'wide'"),
    "yaml": ("P_left: [[1, 2]\n  bad: }",
             "invalid YAML at line 2, column 3: expected ',' or ']', but got '<scalar>'"),
}


@pytest.mark.parametrize("case", CASES)
def test_validation_messages(tmp_path, case):
    content, msg = CASES[case]
    with pytest.raises(RiverbedError) as e:
        load(tmp_path, content)
    assert str(e.value) == f"{tmp_path / 'pair.yaml'}: {msg}"


def test_file_problems(tmp_path):
    with pytest.raises(RiverbedError, match=r"nope.yaml: file not found$"):
        load_pairfile(tmp_path / "nope.yaml")
    (tmp_path / "p.json").write_text('{"P_left": [1,}')
    with pytest.raises(RiverbedError) as e:
        load_pairfile(tmp_path / "p.json")
    assert str(e.value) == f"{tmp_path / 'p.json'}: invalid JSON at line 1, column 15: Expecting value"
    (tmp_path / "big.yaml").write_bytes(b"#" * 1_000_001)
    with pytest.raises(RiverbedError, match="too large for a pair file"):
        load_pairfile(tmp_path / "big.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(RiverbedError, match=r"not a pair file \(not UTF-8 text\)$"):
        load_pairfile(tmp_path / "bin.yaml")
    # Only the safe loader: a Python object tag is an error, not an object.
    (tmp_path / "evil.yaml").write_text("P_left: !!python/object/apply:os.system ['echo hi']\n")
    with pytest.raises(RiverbedError, match="invalid YAML"):
        load_pairfile(tmp_path / "evil.yaml")


def test_registration_files(tmp_path):
    T = np.array([[0.0, -1, 0, 10.5], [1, 0, 0, -2], [0, 0, 1, 3e-3], [0, 0, 0, 1]])
    (tmp_path / "a.txt").write_text("\n".join(" ".join(str(v) for v in row) for row in T))
    (tmp_path / "b.txt").write_text(", ".join(str(v) for v in T[:3].ravel()))  # KITTI style, 12 numbers
    (tmp_path / "c.yaml").write_text(text(registration=T.tolist()))
    (tmp_path / "d.json").write_text(json.dumps(T.tolist()))
    for name in ("a.txt", "b.txt", "c.yaml", "d.json"):
        assert np.array_equal(load_registration(tmp_path / name), T), name
    (tmp_path / "e.txt").write_text("1 2 3")
    with pytest.raises(RiverbedError) as e:
        load_registration(tmp_path / "e.txt")
    msg = "registration: expected 16 numbers (4x4) or 12 (3x4), got 3 values"
    assert str(e.value) == f"{tmp_path / 'e.txt'}: {msg}"
    (tmp_path / "f.yaml").write_text("origin: [1, 2, 3]\n")
    with pytest.raises(RiverbedError, match=r"f.yaml: registration: missing \(expected a 4x4 matrix\)$"):
        load_registration(tmp_path / "f.yaml")


KITTI = """P0: 7.215377e+02 0 6.095593e+02 0 0 7.215377e+02 1.728540e+02 0 0 0 1 0
P2: 7.215377e+02 0 6.095593e+02 4.485728e+01 0 7.215377e+02 1.728540e+02 2.163791e-01 0 0 1 2.745884e-03
P3: 7.215377e+02 0 6.095593e+02 -3.395242e+02 0 7.215377e+02 1.728540e+02 2.199936e+00 0 0 1 2.729905e-03
R0_rect: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 \
4.351614e-03 9.999631e-01
Tr_velo_to_cam: 7.533745e-03 -9.999714e-01 -6.166020e-04 -4.069766e-03 1.480249e-02 7.280733e-04 \
-9.998902e-01 -7.631618e-02 9.998621e-01 7.523790e-03 1.480755e-02 -2.717806e-01
"""


def test_kitti_and_middlebury_importers(tmp_path):
    (tmp_path / "calib.txt").write_text(KITTI)
    pair = kitti_pair(tmp_path / "calib.txt")
    assert not pair.exactly_rectified  # camera 3 is 2.7 mm off camera 2's baseline
    assert pair.baseline == pytest.approx(0.5327, abs=1e-4) and pair.focal == 721.5377
    R0 = np.eye(4)
    R0[:3, :3] = np.array(KITTI.split("R0_rect:")[1].split("\n")[0].split(), float).reshape(3, 3)
    assert np.allclose(pair.registration[:3, :3], R0[:3, :3] @ np.array(
        KITTI.split("Tr_velo_to_cam:")[1].split(), float).reshape(3, 4)[:, :3])
    (tmp_path / "short.txt").write_text(KITTI.replace("2.729905e-03", ""))
    with pytest.raises(RiverbedError) as e:
        kitti_pair(tmp_path / "short.txt")
    assert str(e.value) == f"{tmp_path / 'short.txt'}: P3: expected 12 numbers, got 11"
    (tmp_path / "m.txt").write_text("cam0=[1000 0 500; 0 1000 400; 0 0 1]\n"
                                    "cam1=[1000 0 500; 0 1001 400; 0 0 1]\nbaseline=100\n")
    with pytest.raises(RiverbedError) as e:
        middlebury_pair(tmp_path / "m.txt")
    msg = "cam0 and cam1 differ in focal length or cy: not a rectified pair"
    assert str(e.value) == f"{tmp_path / 'm.txt'}: {msg}"
    (tmp_path / "m2.txt").write_text("cam0=[1000 0 500 0 1000 400 0 0 1]\n"
                                     "cam1=[1000 0 500; 0 1000 400; 0 0 1]\nbaseline=100\n")
    with pytest.raises(RiverbedError) as e:
        middlebury_pair(tmp_path / "m2.txt")
    assert str(e.value) == f"{tmp_path / 'm2.txt'}: cam0: expected a 3x3 matrix, got 1 rows"


def test_unknown_crs(tmp_path):
    with pytest.raises(RiverbedError) as e:
        load(tmp_path, text(crs="EPSG:99999999"))
    assert str(e.value) == f"{tmp_path / 'pair.yaml'}: crs: unknown CRS 'EPSG:99999999'"
