#!/usr/bin/env python3
"""Fetch (or check) the browser libraries the console and the API docs serve from the package.

The console's 3D view (three.js, urdf-loader) and the offline API docs (swagger-ui-dist, redoc)
are released npm packages. Their built files are kept in ``service/console/vendor/NAME/`` with
their licence files, so installing the package needs no npm and a browser fetches nothing from
the internet. This script is how they got there and how they are checked:

    python scripts/fetch_console_vendor.py            # fetch with `npm pack`, verify, write
    python scripts/fetch_console_vendor.py --check    # verify the vendored files (no network)
    python scripts/fetch_console_vendor.py --print-hashes   # after changing a version: new hashes

Each file is pinned by its package version and its SHA-256; a fetched tarball whose files do not
match is refused and nothing is written. ``npm pack`` also checks the registry's integrity hash of
the tarball it downloads.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENDOR = ROOT / "service" / "console" / "vendor"


@dataclass(frozen=True)
class Package:
    """One npm package: its version and the files kept (paths in the tarball)."""

    name: str
    version: str
    files: tuple[str, ...]
    #: A licence file to write when the package ships none: (file name, SPDX id, package whose file holds that text).
    licence_from: tuple[str, str, str] | None = None


PACKAGES: list[Package] = [
    Package("three", "0.187.0", (
        "LICENSE",
        "build/three.module.js",
        "build/three.core.js",
        "examples/jsm/controls/OrbitControls.js",
        "examples/jsm/loaders/STLLoader.js",
        "examples/jsm/loaders/OBJLoader.js",
        "examples/jsm/loaders/ColladaLoader.js",
        "examples/jsm/loaders/TGALoader.js",
        "examples/jsm/loaders/collada/ColladaParser.js",
        "examples/jsm/loaders/collada/ColladaComposer.js",
    )),
    # urdf-loader's tarball has no licence file; its package.json says Apache-2.0, whose text is
    # taken from swagger-ui-dist's LICENSE (the same licence, verbatim).
    Package("urdf-loader", "0.13.1", (
        "package.json",
        "src/URDFLoader.js",
        "src/URDFClasses.js",
    ), licence_from=("LICENSE", "Apache-2.0", "swagger-ui-dist")),
    Package("swagger-ui-dist", "5.35.0", (
        "LICENSE",
        "NOTICE",
        "swagger-ui-bundle.js",
        "swagger-ui.css",
    )),
    Package("redoc", "3.0.1", (
        "LICENSE",
        "bundles/redoc.standalone.js",
    )),
]

#: SHA-256 of every vendored file, by package and path in the tarball (kept apart from the list
#: above so that --print-hashes can regenerate this block alone).
HASHES: dict[str, dict[str, str]] = {
    'three': {
        'LICENSE': '8b378ebe60e2fe500158cb0ac71cb5e8b7d92953c2abcc63a0eb90499653b5bc',
        'build/three.module.js': '104f56145899722094556490d787aae0617cc2fc3382f31df02d724ea1aee341',
        'build/three.core.js': '613e370f76638fdef83926642bf256dc9615684922de1ce1f63a8583e5d78578',
        'examples/jsm/controls/OrbitControls.js': 'e7fca2fe9e7670a828af9b28084669a5909445b7f36f1f26cee9bf8f2961c32c',
        'examples/jsm/loaders/OBJLoader.js': '355484026ac163fdeceececaa943b0473a2e169444015cd2209cc7d27b5b894d',
        'examples/jsm/loaders/STLLoader.js': 'a07441b8cd812faf8049741fe5e95373b19547e4038694753dfec26fe230a7eb',
        'examples/jsm/loaders/ColladaLoader.js': '539406f55a8b7aaafecb00672d0a76f9f393b81c1eacb6131b8ee9431f0d14ac',
        'examples/jsm/loaders/TGALoader.js': '034c95f0a27380ec2ce14aa0a5eb2a937444fd90ccc95f6be58c4cf3c283a2b4',
        'examples/jsm/loaders/collada/ColladaParser.js': 'd9532ab17f1d9e2919deba8029d759d5dcaed2f21195ded9e29491f719b1a0c6',
        'examples/jsm/loaders/collada/ColladaComposer.js': 'eb262d262790a59d3e3b3c50abc56d565f6d97a34a3979151321da73ab9846a1',
    },
    'urdf-loader': {
        'package.json': 'd4134ad13b0a5a1abd7ee1d6178c1f55dcfcfa0bf61b090e46620b5e05c27bb2',
        'src/URDFLoader.js': '51a42cfedcebe1891791f7d0935b5c47ac7d3c9c7d30641b831029d5608bf8ef',
        'src/URDFClasses.js': 'ff7578fc62d0933296a2ca30d2bdb7a856f91871f58fe7857dda4685da45bada',
    },
    'swagger-ui-dist': {
        'LICENSE': 'cfc7749b96f63bd31c3c42b5c471bf756814053e847c10f3eb003417bc523d30',
        'NOTICE': '0d20d1adef18aee3f40dd258172155521ce702ac445cb5f7b7d60ed32dad2fb2',
        'swagger-ui-bundle.js': 'e6a898692f2d768e807c3ba4626068a69a2c5dd960dd6c76f3e4d3a3de180af2',
        'swagger-ui.css': '5ed08757e53da3e026d6cbecc61fe5d43585c9560b302d534ad56692519a273d',
    },
    'redoc': {
        'LICENSE': '02c01d2ca84c2e845a48602cbb51c82b4fa25120b30b7e85045d940db50d15eb',
        'bundles/redoc.standalone.js': '8c70c2de83d33e33a75b225e573d6d9fe851f066f824b44b1637d831d52d7543',
    },
}


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def npm_pack(pkg: Package, workdir: Path) -> dict[str, bytes]:
    """Download ``name@version`` with ``npm pack`` and return the kept files' bytes."""
    spec = f"{pkg.name}@{pkg.version}"
    try:
        out = subprocess.run(["npm", "pack", spec, "--silent", "--pack-destination", str(workdir)],
                             check=True, capture_output=True, text=True, timeout=300).stdout.strip().splitlines()
    except FileNotFoundError:
        sys.exit("npm is not installed; it is needed only to fetch the vendored files again (--check needs none)")
    except subprocess.CalledProcessError as exc:
        sys.exit(f"npm pack {spec} failed: {exc.stderr.strip()}")
    tarball = workdir / out[-1]
    found: dict[str, bytes] = {}
    with tarfile.open(tarball, "r:gz") as tar:
        for member in tar.getmembers():
            rel = member.name.split("/", 1)[1] if "/" in member.name else member.name
            if member.isfile() and rel in pkg.files:
                extracted = tar.extractfile(member)
                assert extracted is not None
                found[rel] = extracted.read()
    missing = sorted(set(pkg.files) - set(found))
    if missing:
        sys.exit(f"{spec}: the tarball lacks {missing}")
    return found


def licence_text(pkg: Package, fetched: dict[str, dict[str, bytes]]) -> bytes | None:
    if pkg.licence_from is None:
        return None
    _, spdx, source = pkg.licence_from
    header = (f"{pkg.name} {pkg.version} is licensed under {spdx} (the \"license\" field of its package.json).\n"
              f"Its npm package ships no licence file; the licence's text follows, as shipped by {source}.\n\n")
    return header.encode() + fetched[source]["LICENSE"]


def expected(pkg: Package, rel: str) -> str:
    return HASHES.get(pkg.name, {}).get(rel, "")


def check() -> int:
    """Compare the vendored files with the pinned hashes; 0 when every one matches."""
    bad = 0
    for pkg in PACKAGES:
        for rel in pkg.files:
            path = VENDOR / pkg.name / rel
            want = expected(pkg, rel)
            if not path.is_file():
                print(f"MISSING  {pkg.name}@{pkg.version} {rel}")
                bad += 1
            elif sha256(path.read_bytes()) != want:
                print(f"MISMATCH {pkg.name}@{pkg.version} {rel}")
                bad += 1
        if pkg.licence_from is not None and not (VENDOR / pkg.name / pkg.licence_from[0]).is_file():
            print(f"MISSING  {pkg.name} {pkg.licence_from[0]}")
            bad += 1
    print("vendored files: " + ("all match their pinned versions and hashes" if not bad else f"{bad} problem(s)"))
    return 1 if bad else 0


def fetch(print_hashes: bool) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        fetched = {pkg.name: npm_pack(pkg, Path(tmp)) for pkg in PACKAGES}
    if print_hashes:
        print("HASHES: dict[str, dict[str, str]] = {")
        for pkg in PACKAGES:
            print(f"    {pkg.name!r}: {{")
            for rel in pkg.files:
                print(f"        {rel!r}: {sha256(fetched[pkg.name][rel])!r},")
            print("    },")
        print("}")
        return 0
    wrong = [f"{pkg.name}@{pkg.version} {rel}" for pkg in PACKAGES for rel in pkg.files
             if sha256(fetched[pkg.name][rel]) != expected(pkg, rel)]
    if wrong:
        print("refused: these fetched files do not match their pinned SHA-256 (nothing written):\n  " + "\n  ".join(wrong))
        return 1
    for pkg in PACKAGES:
        for rel, data in fetched[pkg.name].items():
            path = VENDOR / pkg.name / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        text = licence_text(pkg, fetched)
        if text is not None:
            (VENDOR / pkg.name / pkg.licence_from[0]).write_bytes(text)  # type: ignore[index]
        print(f"wrote {pkg.name}@{pkg.version}: {len(pkg.files)} file(s)")
    return check()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="verify the vendored files against the pinned hashes")
    ap.add_argument("--print-hashes", action="store_true", help="fetch and print the HASHES block for new versions")
    args = ap.parse_args(argv)
    return check() if args.check else fetch(args.print_hashes)


if __name__ == "__main__":
    sys.exit(main())
