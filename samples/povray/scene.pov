// proden sample scene for POV-Ray 3.7: one independent pass (1 sample per pixel) per render.
//
//   povray +I scene.pov +L<dir of this file> Declare=Pass=<n> +W128 +H128 -A +FE +O pass.exr -D +WT1
//
// All randomness comes from Pass via proden_pass.inc: the camera gets one sub-pixel jitter and
// one lens position (thin-lens depth of field), the area light becomes one random point light
// on its rectangle (soft shadows over passes), and the glossy sphere's micro-bump normal is
// translated randomly (blurry reflections with per-pixel noise). No area_light, focal_blur,
// antialiasing or radiosity: those would repeat the same pattern in every pass.
#version 3.7;
#include "proden_pass.inc"

global_settings {
  assumed_gamma 1.0
  max_trace_level 8
  ambient_light rgb 0
}

// Draw order is fixed: camera (4 draws), light (2), glossy bumps (3).
Proden_Camera(<0.6, 1.5, -5.2>, <0, 0.7, 0>, y, 40, 0.18, vlength(<0, 0.7, 0> - <0.6, 1.5, -5.2>))

// Rectangular area light 1.6 x 1.2 above and to the left, sampled by one point per pass.
#declare LightC = <-2.5, 5.0, -2.0>;
#declare LightA1 = <1.6, 0, 0>;
#declare LightA2 = <0, 0, 1.2>;
#declare LightP = Proden_Rect(LightC, LightA1, LightA2);
light_source { LightP color rgb <1.0, 0.92, 0.8> * 30 fade_distance 1 fade_power 2 }
// visible emitter (does not cast shadows, not lit)
box { LightC - LightA1 / 2 - LightA2 / 2, LightC + LightA1 / 2 + LightA2 / 2 + <0, 0.01, 0>
  pigment { rgb <1.0, 0.92, 0.8> } finish { emission 8 diffuse 0 } no_shadow }
// weak fill from the sky
light_source { <3, 8, -6> color rgb <0.35, 0.4, 0.5> shadowless }

sky_sphere { pigment { gradient y color_map { [0 rgb <0.9, 0.85, 0.8> * 0.6] [1 rgb <0.2, 0.35, 0.7> * 0.6] } } }

plane { y, 0
  pigment { checker rgb <0.8, 0.78, 0.7> rgb <0.1, 0.1, 0.12> scale 0.25 }
  finish { diffuse 0.8 specular 0.1 reflection 0.05 } }

// in-focus glossy sphere with micro-bumps moved per pass
#declare BumpT = <Proden_Rand(), Proden_Rand(), Proden_Rand()> * 100;
sphere { <0, 0.7, 0>, 0.7
  pigment { rgb <0.85, 0.75, 0.55> }
  normal { bumps 0.35 scale 0.003 translate BumpT }
  finish { diffuse 0.15 specular 0.6 roughness 0.01 reflection { 0.7 metallic } } }

// near, out-of-focus textured box
box { <-0.4, 0, -0.4>, <0.4, 0.8, 0.4> rotate y * 30 translate <-1.0, 0, -2.6>
  pigment { wood turbulence 0.4 scale 0.08 color_map { [0 rgb <0.6, 0.35, 0.15>] [1 rgb <0.3, 0.15, 0.05>] } }
  finish { diffuse 0.8 specular 0.2 } }

// far, out-of-focus glass sphere and a striped cylinder
sphere { <1.6, 0.6, 3.0>, 0.6
  pigment { rgbf <0.9, 1.0, 0.95, 0.9> }
  finish { diffuse 0.05 specular 0.8 reflection 0.08 }
  interior { ior 1.5 } }
cylinder { <-1.8, 0, 3.5>, <-1.8, 2.0, 3.5>, 0.4
  pigment { gradient y color_map { [0.5 rgb <0.7, 0.1, 0.1>] [0.5 rgb <0.9, 0.9, 0.9>] } scale 0.1 }
  finish { diffuse 0.8 } }
