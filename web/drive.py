"""Driving a robot from the dashboard: the arrows, the keyboard, and what a hold means.

The arrows are viser buttons with a *hold* callback: while one is held the browser sends a
message ``DRIVE_HZ`` times a second, each of which renews a teleop command whose time-to-live
is ``HOLD_TTL_S`` (:meth:`server.services.control.ControlService.teleop`); releasing the
button clicks it, which stops the robot at once. So the robot drives exactly while an arrow is
held, and stops by itself within ``HOLD_TTL_S`` when the page goes away (a closed tab, a
dropped connection: no more messages).

viser has no key-up events, so the keyboard goes through the arrows: a small script (the
inline handler of an image that fails to load, the one way viser's HTML element runs code)
presses the arrow button of a key on key-down and releases it on key-up, and releases every
held arrow (by key, mouse or finger) when the page is hidden, closed or loses focus. Keys:
the arrow keys and W A S D; they drive only while the arrows are shown, and never while
typing in a text field. The script
sends nothing of its own: every command goes through viser's connection and the same checks
as a click.
"""

from __future__ import annotations

from dataclasses import dataclass

DRIVE_HZ = 10.0
"""Hold messages per second while an arrow is held."""
HOLD_TTL_S = 0.75
"""A held arrow's command stays in force this long after its last hold message, seconds. A
browser's timers stall for 0.5 s at times on a busy machine (measured in headless Chromium on
2 shared cores: 100 ms intervals came 528 and 642 ms apart); a shorter time made the robot
stutter while the key was held. Releasing the arrow, hiding the page or closing it stops the
robot at once; this is only the bound for a browser that froze."""


@dataclass(frozen=True)
class Direction:
    """One arrow: its button label, the keys that hold it, and its sign on ``v`` and ``w``."""

    name: str
    label: str
    keys: tuple[str, ...]  # KeyboardEvent.code values
    v: int
    w: int


DIRECTIONS = (
    Direction("forward", "▲ Forward", ("ArrowUp", "KeyW"), 1, 0),
    Direction("left", "◀ Left", ("ArrowLeft", "KeyA"), 0, 1),
    Direction("right", "▶ Right", ("ArrowRight", "KeyD"), 0, -1),
    Direction("back", "▼ Back", ("ArrowDown", "KeyS"), -1, 0),
)


def drive_command(held: set[str], *, speed: float, turn: float) -> tuple[float, float]:
    """``(v, w)`` for the arrows held (names of :data:`DIRECTIONS`): forward and back at
    ``speed`` m/s, left and right at ``turn`` rad/s; both held together cancel; forward with
    left drives an arc."""
    v = sum(d.v for d in DIRECTIONS if d.name in held)
    w = sum(d.w for d in DIRECTIONS if d.name in held)
    return speed * v, turn * w


def keyboard_bridge() -> str:
    """The HTML whose failing image runs the keyboard script once per page (see the module
    docstring). Constant: nothing in it comes from a user."""
    pairs = ",".join(f"{key}:'{d.label}'" for d in DIRECTIONS for key in d.keys)
    arrows = ",".join(f"'{d.label}':1" for d in DIRECTIONS)
    script = (
        "if(!window.teachrepeatKeys){window.teachrepeatKeys=1;"
        f"var labels={{{pairs}}};var arrows={{{arrows}}};var held={{}};var pointed=null;"
        "function find(label){var bs=document.querySelectorAll('button');"
        "for(var i=0;i<bs.length;i++){if(bs[i].textContent.trim()===label){return bs[i];}}"
        "return null;}"
        "function ev(type){return new PointerEvent(type,{bubbles:true,cancelable:true,"
        "button:0,buttons:1,pointerId:1,isPrimary:true,pointerType:'mouse'});}"
        "function press(code){var b=find(labels[code]);if(!b){return;}held[code]=b;"
        "b.dispatchEvent(ev('pointerdown'));}"
        "function release(code){var b=held[code];delete held[code];if(!b){return;}"
        "b.dispatchEvent(ev('pointerup'));b.click();}"
        # an arrow held with the mouse or a finger: released too when the page goes away
        "document.addEventListener('pointerdown',function(e){var b=e.target.closest?"
        "e.target.closest('button'):null;if(b&&arrows[b.textContent.trim()]){pointed=b;}},true);"
        "document.addEventListener('pointerup',function(){pointed=null;},true);"
        "function releaseAll(){for(var code in held){release(code);}"
        "if(pointed){var b=pointed;pointed=null;b.dispatchEvent(ev('pointerup'));b.click();}}"
        "function typing(e){var t=e.target;return !!t&&(t.tagName==='INPUT'||"
        "t.tagName==='TEXTAREA'||t.tagName==='SELECT'||t.isContentEditable);}"
        "window.addEventListener('keydown',function(e){if(!(e.code in labels)||typing(e)){"
        "return;}e.preventDefault();e.stopImmediatePropagation();"
        "if(!e.repeat&&!held[e.code]){press(e.code);}},true);"
        "window.addEventListener('keyup',function(e){if(!(e.code in labels)||typing(e)){"
        "return;}e.preventDefault();e.stopImmediatePropagation();release(e.code);},true);"
        "window.addEventListener('blur',releaseAll);"
        "window.addEventListener('pagehide',releaseAll);"
        "document.addEventListener('visibilitychange',function(){if(document.hidden){"
        "releaseAll();}});}"
    )
    if '"' in script or "&" in script.replace("&&", ""):
        raise ValueError("the keyboard script must hold no double quote and no lone &")
    return f'<img src="data:," alt="" style="display:none" onerror="{script}">'
