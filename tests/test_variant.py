"""Mitsuba variant selection: which libLLVM is usable, and what the user is told."""

import pytest

from renderers.variant import (
    FAST_PATH_HINT,
    MIN_LLVM_MAJOR,
    find_libllvm,
    llvm_major,
    select_variant,
)


@pytest.mark.parametrize(
    "path, major",
    [
        ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", 19),
        ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
        ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", 15),
        ("/usr/lib/llvm-17/lib/libLLVM.so", 17),
        ("/opt/homebrew/opt/llvm/lib/libLLVM.18.dylib", 18),
        ("/usr/lib/libfoo.so", None),
    ],
)
def test_llvm_major(path, major):
    assert llvm_major(path) == major


def test_found_llvm_is_new_enough():
    found = find_libllvm()
    assert found is None or found[1] >= MIN_LLVM_MAJOR


def test_unknown_variant_is_refused():
    with pytest.raises(ValueError, match="variant"):
        select_variant("opengl")


def test_fast_path_hint_says_what_to_install():
    assert "apt-get install libllvm19" in FAST_PATH_HINT and "DRJIT_LIBLLVM_PATH" in FAST_PATH_HINT


def test_chosen_variant_is_the_fastest_available(variant):
    expected = "llvm_ad_rgb" if find_libllvm() else "scalar_rgb"
    assert variant in ("cuda_ad_rgb", expected)
