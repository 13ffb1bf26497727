// Blinn-Phong lighting with one directional light.
uniform vec3 u_light_direction;  // unit vector towards the light, world space
uniform vec3 u_light_colour;
uniform float u_ambient;
uniform vec3 u_material_colour;
uniform float u_specular;
uniform float u_shininess;
uniform vec3 u_eye;

vec3 blinn_phong(vec3 world, vec3 n) {
    vec3 view = normalize(u_eye - world);
    if (dot(n, view) < 0.0) {
        n = -n;  // two-sided: sheets and back faces are lit from the side we see
    }
    vec3 h = normalize(u_light_direction + view);
    float diffuse = max(dot(n, u_light_direction), 0.0);
    float spec = diffuse > 0.0 ? pow(max(dot(n, h), 0.0), u_shininess) : 0.0;
    return u_material_colour * (u_ambient + (1.0 - u_ambient) * diffuse) * u_light_colour
        + u_specular * spec * u_light_colour;
}
