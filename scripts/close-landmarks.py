#!/usr/bin/env python3
"""Pairs of confirmed poles (trees) or points in a map.json closer than a Mahalanobis distance.

    scripts/close-landmarks.py MAP.json [DISTANCE=3]

The distance of two centres uses the sum of their marginal covariances (map.json keeps each
feature's own block, not the cross-covariance), so it is an approximation of the joint test
the EKF's merging uses. Prints the number of features and of pairs within DISTANCE.
Needs numpy.
"""
import json
import sys

import numpy as np


def centres(path):
    with open(path) as f:
        features = json.load(f)["features"]
    out = []
    for feature in features:
        if not feature.get("confirmed") or feature["covariance"] is None:
            continue
        cov = np.array(feature["covariance"])
        if feature["type"] == "pole":
            out.append((np.array(feature["feature"]["centre"]), cov[1:3, 1:3]))
        elif feature["type"] == "point":
            out.append((np.array(feature["feature"]["position"][:2]), cov[0:2, 0:2]))
    return out


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    limit = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
    found = centres(sys.argv[1])
    close = 0
    for i, (a, ca) in enumerate(found):
        for b, cb in found[i + 1 :]:
            d = a - b
            if d @ np.linalg.solve(ca + cb, d) <= limit * limit:
                close += 1
    print(f"{len(found)} landmarks, {close} pairs within Mahalanobis distance {limit}")


if __name__ == "__main__":
    main()
