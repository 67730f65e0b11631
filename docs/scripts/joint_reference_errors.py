"""Write docs/_static/joint/reference_sigma.txt: the reference error of Fig. 9, per test.

The error ``sigma_rel`` that :func:`lensdual.sensitivity.detection_snr_map`
divides the sub-halo's flux excess by, at the SMACS0723 analogue's reference
pair (:func:`lensdual.sensitivity.smacs0723_reference`), for the geometric
test and for the joint test (2 % flux errors per image and band), at several
position errors. A detection SNR is the signal over ``sigma_rel``, so every
SNR of the map scales by the ratio of the two. Run from the repository root::

    python docs/scripts/joint_reference_errors.py
"""

from pathlib import Path

import astropy.units as u

from lensdual.sensitivity import smacs0723_reference

ROOT = Path(__file__).resolve().parents[2]


def main():
    lines = ["sigma_pos_mas  sigma_rel_geometric  sigma_rel_joint  snr_ratio"]
    for mas in (60, 20, 5, 1):
        sp = mas * u.mas
        geo = smacs0723_reference(sigma_pos=sp)["sigma_rel"]
        joint = smacs0723_reference(sigma_pos=sp, test="joint", flux_rel_err=0.02)["sigma_rel"]
        lines.append(f"{mas:13d}  {geo:19.4f}  {joint:15.4f}  {geo / joint:9.1f}")
    out = ROOT / "docs" / "_static" / "joint" / "reference_sigma.txt"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
