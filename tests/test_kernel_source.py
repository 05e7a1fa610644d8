"""Rules of the OpenCL sources (kernels/), checked on the text: every function that is
not a __kernel is KD_INLINE (kernels/inline.h: Intel's CPU runtime miscompiles calls it
does not inline that pass 3-element vectors, tests/repros/intel_cpu_vec3_call.py)."""
import re

from kdray.device import KERNEL_DIR

# a function definition or declaration at the start of a line: return type, name, "("
_FUNCTION = re.compile(r"^(?:KD_INLINE\s+)?(?:__kernel\s+)?[A-Za-z_]\w*(?:\s+|\s*\*\s*)([A-Za-z_]\w*)\(")
_ALONE = re.compile(r"^KD_INLINE\s*(/\*.*)?$")     # KD_INLINE on a line of its own
_NOT_TYPES = {"return", "typedef", "else", "if", "for", "while", "switch", "defined"}


def functions(text):
    """[(name, annotated)] of the functions defined at the top level of `text`: annotated
    when KD_INLINE precedes the definition (on its line or alone on the line before)."""
    lines = text.splitlines()
    found = []
    for i, line in enumerate(lines):
        m = _FUNCTION.match(line)
        if not m or line.split()[0] in _NOT_TYPES or line.rstrip().endswith(";"):
            continue
        before = lines[i - 1].strip() if i else ""
        kernel = before.startswith("__kernel") or line.startswith("__kernel")
        annotated = line.startswith("KD_INLINE") or _ALONE.match(before) is not None
        found.append((m.group(1), kernel or annotated))
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
