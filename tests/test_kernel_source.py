"""Rules of the OpenCL sources (kernels/), checked on the text: every function that is
not a __kernel is KD_INLINE (kernels/inline.h: Intel's CPU runtime miscompiles calls it
does not inline that pass 3-element vectors, tests/repros/intel_cpu_vec3_call.py), or
KD_CALLED with no 3-element vector among its parameters or its return type."""
import re

from kdray.device import KERNEL_DIR

# a function definition or declaration at the start of a line: return type, name, "("
_FUNCTION = re.compile(r"^(?:KD_INLINE\s+)?(?:__kernel\s+)?[A-Za-z_]\w*(?:\s+|\s*\*\s*)([A-Za-z_]\w*)\(")
_ALONE = re.compile(r"^KD_INLINE\s*(/\*.*)?$")     # KD_INLINE on a line of its own
_CALLED = re.compile(r"^KD_CALLED\s*(/\*.*)?$")     # KD_CALLED on a line of its own
_VEC3 = re.compile(r"\b(?:float|double|int|uint|short|ushort|char|uchar|long|ulong|half)3\b")
_NOT_TYPES = {"return", "typedef", "else", "if", "for", "while", "switch", "defined"}


def signature(lines, i):
    """The text of the definition starting at line i, up to its body's "{"."""
    text = ""
    for line in lines[i:]:
        text += line.split("{")[0] + " "
        if "{" in line:
            break
    return text


def functions(text):
    """[(name, annotated)] of the functions defined at the top level of `text`: annotated
    when KD_INLINE precedes the definition (on its line or alone on the line before), or
    KD_CALLED alone on the line before with no 3-element vector in its signature."""
    lines = text.splitlines()
    found = []
    for i, line in enumerate(lines):
        m = _FUNCTION.match(line)
        if not m or line.split()[0] in _NOT_TYPES or line.rstrip().endswith(";"):
            continue
        before = lines[i - 1].strip() if i else ""
        kernel = before.startswith("__kernel") or line.startswith("__kernel")
        annotated = line.startswith("KD_INLINE") or _ALONE.match(before) is not None
        called = _CALLED.match(before) is not None and not _VEC3.search(signature(lines, i))
        found.append((m.group(1), kernel or annotated or called))
    return found


def test_every_function_is_inlined():
    seen = {}
    for path in sorted(KERNEL_DIR.iterdir()):
        if path.suffix in (".cl", ".h"):
            for name, ok in functions(path.read_text(encoding="utf-8")):
                seen[f"{path.name}:{name}"] = ok
    assert len(seen) > 40                       # the parser finds the functions
    assert "triangle.cl:intersect_triangle" in seen and "render.cl:trace_rays" in seen
    missing = [name for name, ok in seen.items() if not ok]
    assert not missing, f"functions without KD_INLINE: {missing}"


def test_the_check_sees_a_function_without_it():
    text = "KD_INLINE float a(float x) { return x; }\nfloat3 b(float3 v)\n{\n    return v;\n}\n"
    assert functions(text) == [("a", True), ("b", False)]


def test_a_call_takes_no_three_element_vector():
    """KD_CALLED passes for a signature without 3-element vectors only."""
    text = ("KD_CALLED\nfloat a(float16 x,\n        float y)\n{\n    return y;\n}\n"
            "KD_CALLED\nfloat b(float16 x,\n        float3 y)\n{\n    return y.x;\n}\n"
            "KD_CALLED\nint3 c(float x)\n{\n    return (int3)(0);\n}\n")
    assert functions(text) == [("a", True), ("b", False), ("c", False)]
