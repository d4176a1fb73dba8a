"""GLSL sources of the fake's EGL renderer (``sim.render.EglRenderer``): TinyRenderer's shading, optionally with
shadows from a shadow map of the scene's directional light.

TinyRenderer's fragment shading (PyBullet 3.2, shadows off): 8-bit colour c, unit normal n, light direction l
(unit, world); r = reflect(-l, n); value = floor(ambient c + (kd max(n.l, 0) + ks max(r_z, 0)^shininess) c
light_colour), at most 255. Per pixel for smooth parts; per triangle (in the vertex shader) for flat ones, whose
pixels all have the triangle's normal: the same values, at a fraction of the cost.

With shadows (``sources(shadows=True)``) the direct term (diffuse + specular) is scaled by ``1 - shadow_strength``
where the light is blocked: a depth map drawn from the light (orthographic, ``shadow_from_link`` maps a link's
points to its texture coordinates and depth in 0..1) read once with OpenGL's 2x2 comparison filter: a soft edge
one texel wide (``render.SHADOW_MAP_SIZE``), so flat parts shade per pixel there.
"""

_SHADING = """
uniform vec3 colour;             // 0..255 (untextured parts)
uniform vec3 light_direction;    // unit, world
uniform vec3 light_colour;
uniform float ambient, diffuse, specular, shininess;
uniform float scene_alpha;       // written as alpha: 0 for the parts riding with the camera, 1 elsewhere
float lighting(vec3 world_normal) {
    vec3 n = normalize(world_normal);
    float n_dot_l = dot(n, light_direction);
    vec3 reflection = normalize(n * (2.0 * n_dot_l) - light_direction);
    return diffuse * max(n_dot_l, 0.0) + specular * pow(max(reflection.z, 0.0), shininess);
}
vec3 shade(float lit, vec3 colour) {
    return min(floor(ambient * colour + lit * colour * light_colour), vec3(255.0)) / 255.0;
}
"""
_SUNLIT = """
#ifdef SHADOWS
in vec3 shadow_position;
uniform sampler2DShadow shadow_map;
uniform float shadow_strength, shadow_bias;   // share of the direct light blocked; depth (0..1)
float sunlit() {       // 1 in full light, 1 - shadow_strength in full shadow
    float seen = texture(shadow_map, vec3(shadow_position.xy, shadow_position.z - shadow_bias));   // 0..1, 2x2 filtered
    return 1.0 - shadow_strength * (1.0 - seen);
}
#else
float sunlit() { return 1.0; }
#endif
"""
_VERTEX_INPUTS = """
layout(location = 0) in vec3 position;   // m, link frame
layout(location = 1) in vec3 normal;     // link frame
layout(location = 2) in vec2 uv;         // texture coordinates (textured parts)
uniform mat4 clip_from_link;
uniform mat3 world_from_link;
#ifdef SHADOWS
uniform mat4 shadow_from_link;
out vec3 shadow_position;
#define PASS_SHADOW_POSITION shadow_position = (shadow_from_link * vec4(position, 1.0)).xyz;
#else
#define PASS_SHADOW_POSITION
#endif
"""
_PROGRAMS = {    # name: (vertex shader, fragment shader), each after the version line and the SHADOWS switch
    # flat: the light per triangle; shaded in the vertex shader when nothing varies over a triangle
    'flat': (_VERTEX_INPUTS + _SHADING + """
#ifdef SHADOWS
flat out float lit;
#else
flat out vec3 shaded;
#endif
void main() {
    gl_Position = clip_from_link * vec4(position, 1.0);
    PASS_SHADOW_POSITION
#ifdef SHADOWS
    lit = lighting(world_from_link * normal);
#else
    shaded = shade(lighting(world_from_link * normal), colour);
#endif
}
""", _SHADING + _SUNLIT + """
#ifdef SHADOWS
flat in float lit;
#else
flat in vec3 shaded;
#endif
out vec4 fragment;
void main() {
#ifdef SHADOWS
    fragment = vec4(shade(lit * sunlit(), colour), scene_alpha);
#else
    fragment = vec4(shaded, scene_alpha);
#endif
}
"""),
    'smooth': (_VERTEX_INPUTS + """
out vec3 world_normal;
void main() {
    gl_Position = clip_from_link * vec4(position, 1.0);
    PASS_SHADOW_POSITION
    world_normal = world_from_link * normal;
}
""", _SHADING + _SUNLIT + """
in vec3 world_normal;
out vec4 fragment;
void main() { fragment = vec4(shade(lighting(world_normal) * sunlit(), colour), scene_alpha); }
"""),
    # TinyRenderer: the texel (nearest, 8-bit) x rgba, truncated, then shaded; the light per (flat) box triangle
    'textured': (_VERTEX_INPUTS + _SHADING + """
flat out float lit;
out vec2 texture_uv;
void main() {
    gl_Position = clip_from_link * vec4(position, 1.0);
    PASS_SHADOW_POSITION
    lit = lighting(world_from_link * normal);
    texture_uv = uv;
}
""", _SHADING + _SUNLIT + """
flat in float lit;
in vec2 texture_uv;
uniform sampler2D image;
uniform vec3 tint;               // rgba of the shape, 0..1
out vec4 fragment;
void main() {
    fragment = vec4(shade(lit * sunlit(), floor(round(texture(image, texture_uv).rgb * 255.0) * tint)), scene_alpha);
}
"""),
}
# The shadow map: depth as the light sees it (clip_from_link is the light's orthographic projection).
_DEPTH = ("""
layout(location = 0) in vec3 position;
uniform mat4 clip_from_link;
void main() { gl_Position = clip_from_link * vec4(position, 1.0); }
""", """
void main() {}
""")
UNIFORMS = ('clip_from_link', 'world_from_link', 'colour', 'light_direction', 'light_colour', 'ambient', 'diffuse',
            'specular', 'shininess', 'tint', 'image', 'shadow_from_link', 'shadow_map', 'shadow_strength',
            'shadow_bias', 'scene_alpha')


def sources(shadows=False):
    """{program name: (vertex source, fragment source)} of the shading programs ('flat', 'smooth', 'textured'),
    with the shadow-map lookup if ``shadows``, plus 'depth' (the shadow map's pass) if ``shadows``."""
    header = '#version 330 core\n' + ('#define SHADOWS\n' if shadows else '')
    programs = {name: (header + vertex, header + fragment) for name, (vertex, fragment) in _PROGRAMS.items()}
    if shadows:
        programs['depth'] = (header + _DEPTH[0], header + _DEPTH[1])
    return programs
