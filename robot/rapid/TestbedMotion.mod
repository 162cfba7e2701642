MODULE TestbedMotion
  ! The testbed's motion program interpreter: ONE copy of this module in EACH arm's task
  ! (T_ROB_L and T_ROB_R), next to that task's TestbedTask_L / TestbedTask_R and TestbedZones.sys.
  !
  ! Why our own: abb_motion_program_exec's client names a task's program file after the
  ! task's trailing digits, so the YuMi's T_ROB_L and T_ROB_R would share one file and
  ! the second arm's program would overwrite the first's. This module reads the same
  ! binary format (MotionProgram.get_program_bytes: little-endian float32 numbers,
  ! version 10011) from a file FIXED PER TASK (tb_name in the task module), which is
  ! where drivers/yumi/rws_controller.py uploads it. Written for this project from the
  ! Python writer's format; no RAPID code of any other project was used.
  !
  ! What it does (docs/notes/rws.md, "Our RAPID side"):
  !   1. reads and checks the WHOLE file before the first motion (version, tool frame
  !      against tool_pusher's, no EGM, only MoveAbsJ 1, MoveJ 2, MoveL 3 and WaitTime 5,
  !      at most TB_MAX_CMDS commands, no robtarget below tb_floor_z) and holds EVERY
  !      field a file can set to a limit of the controller's (issue 43; robot/README.md,
  !      "The limits a file cannot pass"): no number that is not finite (NaN, inf); each
  !      speed > 0 and at most the cell's cap (v_tcp tb_v_tcp_max, v_ori tb_v_ori_max,
  !      v_reax tb_v_reax_max: the task module's, which the lab sets; v_leax
  !      TB_V_LEAX_MAX); each zonedata field from 0 to z10's (TB_ZONE_MAX and the
  !      TB_*ZONE*_MAX below); each WaitTime from 0 to TB_WAIT_MAX; the work object
  !      wobj0's frames (the identity) or refused. One failed check refuses the file:
  !      an entry that names the command and the field, and nothing moves;
  !   2. runs the commands with tool_pusher (frame AND load from the task module: the
  !      controller's, never the file's) in wobj0 (the frame of the zones and the floor);
  !      ConfJ and ConfL Off, SingArea Wrist; the file's speeds and zones (within the
  !      caps), after VelSet 100, tb_v_tcp_max, so that no move's TCP runs faster than
  !      the cap even if a check above were missed (Technical reference manual - RAPID
  !      Instructions, Functions and Data types, VelSet: Max, a TCP speed in mm/s, limits
  !      the TCP speed of every positioning instruction after it; Override 100 leaves the
  !      programmed speeds as they are).
  !      Joint speeds: speeddata has no per-axis speed. A MoveAbsJ or MoveJ moves the
  !      axes together, and its speed is set by the component that takes longest: the
  !      TCP at v_tcp, the tool's reorientation at v_ori, axis 7 (the YuMi's arm angle,
  !      its rotational external axis) at v_reax (same manual, speeddata). So a joint
  !      move is bounded by the same three caps; the axes' own top speeds are the robot's.
  !   3. waits until the arm is in position (WaitRob InPos) and writes
  !      ErrWrite info (80003) "Testbed Motion Done": task, "seqno <n>", "commands <k>",
  !      the file; or, when it refuses the file, ErrWrite (80001) "Testbed Motion
  !      Failed": reason, the file, the detail, "at byte <offset>". No log file, no
  !      signals: the driver reads the event log only.
  !   4. the stationary world zones are NOT here: this is a program module, which
  !      "Reset RAPID" removes. They are defined at every power on by tb_zones in the
  !      system module TestbedZones.sys from the system module TestbedTask_L / _R's
  !      tb_zone_lo, tb_zone_hi, tb_zone_z and tb_floor_z (issue 29).
  ! main, the task's entry routine, is here (the same in both tasks): it must be in a
  ! program module, and this is the only one of ours.
  ! A motion error (out of reach, collision, a stop, a world zone) is the controller's
  ! own: it stops the task and is in the event log with its own code; the driver
  ! reports it the same.
  ! Routines are global in the task (rapidchecker's grammar has no LOCAL routines); the
  ! tb_ prefix keeps them apart from the task's other names.
  ! The version of these modules' behaviour: bump it whenever they change. The driver
  ! and testbed check read it (RWS); the twin plays the version RAPID_VERSION in
  ! sim_twin/rws/testbed_rapid.py. 2: the world zones (tb_zones). 3: the zones in the
  ! system module TestbedZones (TASK PERS, tb_zones_n), main here, the file's path as
  ! "RAMDISK:/<name>", the error handler closes only a file it opened, the tool load
  ! with the gripper (issue 29). 4: the tool frame is the controller's (tool_pusher in
  ! TestbedTask_L / _R, no longer set from the file): a file whose tframe differs from
  ! it by more than TB_TOOL_MM or TB_TOOL_DEG is refused before any motion; tb_zones
  ! writes "Testbed Zones Active" to the event log (issue 35). 5: every field a file can
  ! set has a limit the controller holds (issue 43): a speed above tb_v_tcp_max,
  ! tb_v_ori_max, tb_v_reax_max (task modules) or TB_V_LEAX_MAX is refused (the file's
  ! v_ori, v_leax, v_reax were replaced by TB_V_ORI, TB_V_LEAX, TB_V_REAX: gone), and
  ! VelSet 100, tb_v_tcp_max runs before the moves; a WaitTime above TB_WAIT_MAX, a
  ! zonedata above z10's, a work object other than wobj0's frames and a number that is
  ! not finite are refused; the moves run in wobj0, never the file's work object.
  CONST num TB_RAPID_VERSION := 5;
  ! The RAM disk device. Technical reference manual - RAPID Instructions, Functions and
  ! Data types (RobotWare 6): Open takes the device as its object and the file name in
  ! \File (its example: Open "HOME:" \File:= "LOGFILE1.DOC", ...); the functions that
  ! take ONE path (FileSize, IsFile) take the device, a slash and the name, as in its
  ! examples "HOME:/..." (FileSize). So the file is opened as TB_DIR \File:=tb_name and
  ! sized (and named in every entry) as tb_path = "RAMDISK:/testbed_T_ROB_L.bin"; the old
  ! TB_DIR + tb_name, "RAMDISK:testbed_T_ROB_L.bin", is not that form (issue 29).
  CONST string TB_DIR := "RAMDISK:";
  CONST num TB_VERSION := 10011;
  CONST num TB_MAX_CMDS := 64;
  CONST string TB_DONE := "Testbed Motion Done";
  CONST string TB_FAILED := "Testbed Motion Failed";
  ! The tool frame check (issue 35; robot/README.md, "The tool frame"): the file's
  ! tframe is what the operator side believes the pusher is (the calibration's
  ! tool_z_mm); the controller's tool_pusher is what was measured on this robot. Apart
  ! by more than 1 mm (translation) or 0.5 deg (rotation): the PC plans for another tool
  ! than the robot runs, and the file is refused.
  CONST num TB_TOOL_MM := 1;
  CONST num TB_TOOL_DEG := 0.5;
  CONST string TB_TOOL_DIFFERS := "Tool frame differs from tool_pusher";
  ! The limits a file cannot pass (issue 43; robot/README.md, "The limits a file cannot
  ! pass"). The caps of the TCP, orientation and axis 7 speeds are the lab's, in the task
  ! module (tb_v_tcp_max, tb_v_ori_max, tb_v_reax_max); these are the module's.
  ! Linear external axes (mm/s): the YuMi has none; the driver writes 1000 (a harmless
  ! value), which the cap lets pass.
  CONST num TB_V_LEAX_MAX := 1000;
  ! WaitTime (s): the driver sends only WaitTime 0 (the program of an arm with nothing
  ! to do); a long wait would hold the task, and with it the other arm's MultiMove start,
  ! after the PC that sent it has gone.
  CONST num TB_WAIT_MAX := 2;
  ! The corner zones: at most z10's (the driver sends z10 for fly-by points and fine
  ! otherwise; zonedata [finep, pzone_tcp, pzone_ori, pzone_eax, zone_ori, zone_leax,
  ! zone_reax], z10 = [FALSE,10,15,15,1.5,15,1.5]): a larger zone cuts a corner by more
  ! than the PC's sweep of the paths allows for. mm, but zone_ori and zone_reax (deg).
  CONST num TB_ZONE_MAX := 10;
  CONST num TB_PZONE_ORI_MAX := 15;
  CONST num TB_PZONE_EAX_MAX := 15;
  CONST num TB_ZONE_ORI_MAX := 1.5;
  CONST num TB_ZONE_LEAX_MAX := 15;
  CONST num TB_ZONE_REAX_MAX := 1.5;
  ! The reasons (a refusal's first line) of these limits.
  CONST string TB_SPEED_OVER := "Speed above the cell's limit";
  CONST string TB_WAIT_OVER := "Wait above the limit";
  CONST string TB_ZONE_OVER := "Corner zone above the limit";
  CONST string TB_WOBJ_REFUSED := "Work object not supported";
  CONST string TB_NOT_FINITE := "Invalid number";

  LOCAL VAR errnum tb_err := -1;
  LOCAL VAR iodev tb_dev;
  ! TRUE from Open to Close: the error handler (and the next run) closes tb_dev only if
  ! it is open (an error before Open, e.g. no file, must not Close a device never
  ! opened). A VAR: PP to Main resets it to FALSE and closes the task's files alike.
  LOCAL VAR bool tb_open := FALSE;
  ! "RAMDISK:/" + tb_name: FileSize's argument and the file named in every entry
  LOCAL VAR string tb_path;
  LOCAL VAR rawbytes tb_raw;
  LOCAL VAR num tb_pos;
  LOCAL VAR num tb_n;
  LOCAL VAR num tb_seqno;
  LOCAL VAR string tb_reason;
  LOCAL VAR string tb_detail;
  ! the refusal's last line: "" = "at byte <offset>"; the tool frame check puts
  ! tool_pusher's frame there (one line of 80 characters holds one frame, not two)
  LOCAL VAR string tb_last;
  ! what is being read ("tooldata", "MoveL cmd_num 3 speeddata"...): a number that is
  ! not finite is refused naming it (tb_num knows no field of its own)
  LOCAL VAR string tb_what;
  LOCAL VAR num tb_op{TB_MAX_CMDS};
  LOCAL VAR num tb_cmd{TB_MAX_CMDS};
  LOCAL VAR robtarget tb_pt{TB_MAX_CMDS};
  LOCAL VAR jointtarget tb_jt{TB_MAX_CMDS};
  LOCAL VAR speeddata tb_speed{TB_MAX_CMDS};
  LOCAL VAR zonedata tb_zone{TB_MAX_CMDS};
  LOCAL VAR num tb_wait{TB_MAX_CMDS};

  ! --- the entry -------------------------------------------------------------------------
  PROC main()
    tb_run;
  ENDPROC

  PROC tb_run()
    VAR num size;
    tb_n := 0;
    tb_pos := 0;
    tb_reason := "";
    tb_detail := "";
    tb_last := "";
    tb_what := "version";
    tb_path := TB_DIR + "/" + tb_name;
    IF tb_err < 0 BookErrNo tb_err;
    ! a run stopped while reading left the file open: close it before opening again
    tb_close;
    size := FileSize(tb_path);
    Open TB_DIR \File:=tb_name, tb_dev \Read \Bin;
    tb_open := TRUE;
    tb_header;
    WHILE tb_pos < size DO
      tb_command;
    ENDWHILE
    tb_close;
    tb_execute;
    ErrWrite \I, TB_DONE, GetTaskName() \RL2:="seqno " + NumToStr(tb_seqno, 0)
      \RL3:="commands " + NumToStr(tb_n, 0) \RL4:=tb_path;
  ERROR
    TEST ERRNO
    CASE ERR_FILEOPEN:
      tb_reason := "Motion program file not found";
      tb_detail := "nothing uploaded";
    CASE ERR_FILEACC:
      tb_reason := "Motion program file not found";
      tb_detail := "nothing uploaded (or not readable)";
    CASE ERR_RANYBIN_EOF:
      tb_reason := "Motion program file truncated";
      tb_detail := "the file ends inside a value";
    CASE tb_err:
      ! tb_reason and tb_detail were set where the file was refused
    DEFAULT:
      ! not a refusal of ours: the controller's own error stops the task
      tb_close;
      RAISE;
    ENDTEST
    tb_close;
    IF tb_last = "" tb_last := "at byte " + NumToStr(tb_pos, 0);
    ErrWrite TB_FAILED, tb_reason \RL2:=tb_path \RL3:=tb_detail \RL4:=tb_last;
    RETURN;
  ENDPROC

  ! Close the program file if (and only if) this task opened it.
  PROC tb_close()
    IF tb_open THEN
      tb_open := FALSE;
      Close tb_dev;
    ENDIF
  ENDPROC

  ! --- reading the file ------------------------------------------------------------------
  PROC tb_fail(string reason, string detail)
    tb_reason := reason;
    tb_detail := detail;
    RAISE tb_err;
  ENDPROC

  ! The next float32 of the file. One whose exponent bits are all ones is an inf or a
  ! NaN: no comparison would refuse it (a NaN is neither above a cap nor at or below
  ! 0), so it is refused here, before it is unpacked. Little-endian (UnpackRawBytes'
  ! default): byte 4 holds the sign and the exponent's seven high bits, the top bit of
  ! byte 3 its lowest.
  FUNC num tb_num()
    VAR num v;
    VAR num hi;
    VAR num lo;
    ReadRawBytes tb_dev, tb_raw, 4 \Time:=5;
    UnpackRawBytes tb_raw, 4, hi \IntX:=USINT;
    UnpackRawBytes tb_raw, 3, lo \IntX:=USINT;
    IF hi MOD 128 = 127 AND lo >= 128 tb_fail TB_NOT_FINITE, tb_what + ": not a finite number";
    UnpackRawBytes tb_raw, 1, v \Float4;
    tb_pos := tb_pos + 4;
    RETURN v;
  ENDFUNC

  FUNC bool tb_bool(string what)
    VAR num v;
    v := tb_num();
    IF v <> 0 AND v <> 1 tb_fail "Invalid bool in motion program", what + " is " + NumToStr(v, 3);
    RETURN v = 1;
  ENDFUNC

  FUNC string tb_str(string what)
    VAR num len;
    VAR string s := "";
    len := tb_num();
    IF len < 0 OR len > 32 OR len <> Round(len) THEN
      tb_fail "Invalid string in motion program", what + " length " + NumToStr(len, 0);
    ENDIF
    ReadRawBytes tb_dev, tb_raw, 32 \Time:=5;
    tb_pos := tb_pos + 32;
    IF len > 0 UnpackRawBytes tb_raw, 1, s \ASCII:=len;
    RETURN s;
  ENDFUNC

  FUNC pose tb_pose()
    VAR pose p;
    p.trans.x := tb_num();
    p.trans.y := tb_num();
    p.trans.z := tb_num();
    p.rot.q1 := tb_num();
    p.rot.q2 := tb_num();
    p.rot.q3 := tb_num();
    p.rot.q4 := tb_num();
    RETURN p;
  ENDFUNC

  FUNC loaddata tb_load()
    VAR loaddata l;
    l.mass := tb_num();
    l.cog.x := tb_num();
    l.cog.y := tb_num();
    l.cog.z := tb_num();
    l.aom.q1 := tb_num();
    l.aom.q2 := tb_num();
    l.aom.q3 := tb_num();
    l.aom.q4 := tb_num();
    l.ix := tb_num();
    l.iy := tb_num();
    l.iz := tb_num();
    RETURN l;
  ENDFUNC

  FUNC extjoint tb_extax()
    VAR extjoint e;
    e.eax_a := tb_num();
    e.eax_b := tb_num();
    e.eax_c := tb_num();
    e.eax_d := tb_num();
    e.eax_e := tb_num();
    e.eax_f := tb_num();
    RETURN e;
  ENDFUNC

  FUNC robtarget tb_robtarget()
    VAR robtarget t;
    VAR pose p;
    p := tb_pose();
    t.trans := p.trans;
    t.rot := p.rot;
    t.robconf.cf1 := tb_num();
    t.robconf.cf4 := tb_num();
    t.robconf.cf6 := tb_num();
    t.robconf.cfx := tb_num();
    t.extax := tb_extax();
    RETURN t;
  ENDFUNC

  FUNC jointtarget tb_jointtarget()
    VAR jointtarget j;
    j.robax.rax_1 := tb_num();
    j.robax.rax_2 := tb_num();
    j.robax.rax_3 := tb_num();
    j.robax.rax_4 := tb_num();
    j.robax.rax_5 := tb_num();
    j.robax.rax_6 := tb_num();
    j.extax := tb_extax();
    RETURN j;
  ENDFUNC

  ! The file's speeds, each above 0 and at most its cap, run as they are (no longer
  ! replaced by the module's: every one is within the cell's limits).
  FUNC speeddata tb_speeddata(string what)
    VAR speeddata s;
    tb_what := what + " speeddata";
    s.v_tcp := tb_num();
    s.v_ori := tb_num();
    s.v_leax := tb_num();
    s.v_reax := tb_num();
    tb_speed_limit what, "v_tcp", s.v_tcp, "tb_v_tcp_max", tb_v_tcp_max;
    tb_speed_limit what, "v_ori", s.v_ori, "tb_v_ori_max", tb_v_ori_max;
    tb_speed_limit what, "v_leax", s.v_leax, "TB_V_LEAX_MAX", TB_V_LEAX_MAX;
    tb_speed_limit what, "v_reax", s.v_reax, "tb_v_reax_max", tb_v_reax_max;
    RETURN s;
  ENDFUNC

  ! The file's zone, each field from 0 (a stop point's) to z10's. finep TRUE (fine) makes
  ! the controller ignore the others; they are checked all the same.
  FUNC zonedata tb_zonedata(string what)
    VAR zonedata z;
    tb_what := what + " zonedata";
    z.finep := tb_bool(what + " finep");
    z.pzone_tcp := tb_num();
    z.pzone_ori := tb_num();
    z.pzone_eax := tb_num();
    z.zone_ori := tb_num();
    z.zone_leax := tb_num();
    z.zone_reax := tb_num();
    tb_zone_limit what, "pzone_tcp", z.pzone_tcp, "TB_ZONE_MAX", TB_ZONE_MAX;
    tb_zone_limit what, "pzone_ori", z.pzone_ori, "TB_PZONE_ORI_MAX", TB_PZONE_ORI_MAX;
    tb_zone_limit what, "pzone_eax", z.pzone_eax, "TB_PZONE_EAX_MAX", TB_PZONE_EAX_MAX;
    tb_zone_limit what, "zone_ori", z.zone_ori, "TB_ZONE_ORI_MAX", TB_ZONE_ORI_MAX;
    tb_zone_limit what, "zone_leax", z.zone_leax, "TB_ZONE_LEAX_MAX", TB_ZONE_LEAX_MAX;
    tb_zone_limit what, "zone_reax", z.zone_reax, "TB_ZONE_REAX_MAX", TB_ZONE_REAX_MAX;
    RETURN z;
  ENDFUNC

  ! A speed: above 0 and at most its cap (the cap named in the detail).
  PROC tb_speed_limit(string what, string field, num v, string name, num cap)
    IF v <= 0 tb_fail "Invalid speed", what + ": " + field + " = " + NumToStr(v, 2);
    tb_over TB_SPEED_OVER, what, field, v, name, cap;
  ENDPROC

  ! A zonedata field: from 0 to its cap.
  PROC tb_zone_limit(string what, string field, num v, string name, num cap)
    IF v < 0 tb_fail "Invalid zone", what + ": " + field + " = " + NumToStr(v, 2);
    tb_over TB_ZONE_OVER, what, field, v, name, cap;
  ENDPROC

  ! Refuse the file with reason when v is above cap: "<what>: <field> <v> > <name> <cap>",
  ! e.g. "MoveL cmd_num 3: v_tcp 1000 > tb_v_tcp_max 150".
  PROC tb_over(string reason, string what, string field, num v, string name, num cap)
    IF v > cap THEN
      tb_fail reason, tb_clip(what + ": " + field + " " + NumToStr(v, 2) + " > " + name + " "
        + NumToStr(cap, 2));
    ENDIF
  ENDPROC

  PROC tb_header()
    VAR num version;
    VAR pose frame;
    VAR loaddata ignored;
    VAR wobjdata file_wobj;
    VAR string stamp;
    version := tb_num();
    IF version <> TB_VERSION THEN
      tb_fail "Invalid motion program file version", NumToStr(version, 0) + " (expected "
        + NumToStr(TB_VERSION, 0) + ")";
    ENDIF
    tb_what := "tooldata";
    IF NOT tb_bool("tool robhold") tb_fail "Stationary tool not supported", "tool robhold";
    ! the pusher's frame and load are the controller's (tool_pusher, the task module):
    ! the file's frame must be the same, its load is not used
    frame := tb_pose();
    tb_tool frame;
    ignored := tb_load();
    ! the work object: wobj0's (the world frame of the zones and the floor), or refused;
    ! the moves run in wobj0 itself
    tb_what := "wobjdata";
    file_wobj.robhold := tb_bool("wobj robhold");
    file_wobj.ufprog := tb_bool("wobj ufprog");
    file_wobj.ufmec := tb_str("wobj ufmec");
    file_wobj.uframe := tb_pose();
    file_wobj.oframe := tb_pose();
    IF file_wobj.robhold OR NOT file_wobj.ufprog OR file_wobj.ufmec <> "" THEN
      tb_fail "Moving work object not supported", "robhold, ufprog or ufmec";
    ENDIF
    tb_identity "uframe", file_wobj.uframe;
    tb_identity "oframe", file_wobj.oframe;
    ! the grip load: the pusher holds nothing
    tb_what := "grip load";
    ignored := tb_load();
    tb_what := "timestamp";
    stamp := tb_str("timestamp");
    tb_what := "seqno";
    tb_seqno := tb_num();
    tb_what := "EGM";
    IF tb_num() <> 0 tb_fail "EGM not supported", "the file asks for an EGM configuration";
  ENDPROC

  ! Refuse the file (before any motion) unless its tool frame is tool_pusher's within
  ! TB_TOOL_MM and TB_TOOL_DEG. tool_pusher is never assigned here.
  PROC tb_tool(pose file)
    VAR num dist;
    VAR num angle;
    dist := Distance(file.trans, tool_pusher.tframe.trans);
    angle := tb_angle(file.rot, tool_pusher.tframe.rot);
    IF dist > TB_TOOL_MM OR angle > TB_TOOL_DEG THEN
      tb_last := tb_clip("tool_pusher " + tb_frame(tool_pusher.tframe));
      tb_fail TB_TOOL_DIFFERS, tb_clip("file " + tb_frame(file));
    ENDIF
  ENDPROC

  ! Refuse the file unless the work object's frame (uframe or oframe) is the identity,
  ! exactly: wobj0's, the world frame the targets, tb_floor_z and the zones are in.
  PROC tb_identity(string field, pose p)
    IF p.trans.x <> 0 OR p.trans.y <> 0 OR p.trans.z <> 0 OR p.rot.q1 <> 1 OR p.rot.q2 <> 0
      OR p.rot.q3 <> 0 OR p.rot.q4 <> 0 THEN
      tb_fail TB_WOBJ_REFUSED, tb_clip(field + " " + tb_frame(p));
    ENDIF
  ENDPROC

  ! The angle (deg) between two orientations: 2 * ACos(|a.b|) for unit quaternions (q
  ! and -q are the same orientation). Computed as 4 * ASin(|a - s b| / 2), s the sign
  ! of a.b: the same angle (|a - s b|^2 = 2 - 2 |a.b|), and well conditioned near 0,
  ! where ACos of a dot product next to 1 resolves only about 0.04 deg in RAPID's
  ! single-precision num. Both are normalised first; a zero quaternion is no
  ! orientation (180).
  FUNC num tb_angle(orient a, orient b)
    VAR num na;
    VAR num nb;
    VAR num s := 1;
    VAR num d;
    na := Sqrt(a.q1 * a.q1 + a.q2 * a.q2 + a.q3 * a.q3 + a.q4 * a.q4);
    nb := Sqrt(b.q1 * b.q1 + b.q2 * b.q2 + b.q3 * b.q3 + b.q4 * b.q4);
    IF na = 0 OR nb = 0 RETURN 180;
    IF a.q1 * b.q1 + a.q2 * b.q2 + a.q3 * b.q3 + a.q4 * b.q4 < 0 s := -1;
    d := Sqrt(Pow(a.q1 / na - s * b.q1 / nb, 2) + Pow(a.q2 / na - s * b.q2 / nb, 2)
      + Pow(a.q3 / na - s * b.q3 / nb, 2) + Pow(a.q4 / na - s * b.q4 / nb, 2)) / 2;
    IF d > 1 d := 1;
    RETURN 4 * ASin(d);
  ENDFUNC

  ! A frame as a line of the entry: [[x,y,z],[q1,q2,q3,q4]], mm to 0.1, q to 0.0001.
  FUNC string tb_frame(pose p)
    RETURN "[[" + NumToStr(p.trans.x, 1) + "," + NumToStr(p.trans.y, 1) + ","
      + NumToStr(p.trans.z, 1) + "],[" + NumToStr(p.rot.q1, 4) + ","
      + NumToStr(p.rot.q2, 4) + "," + NumToStr(p.rot.q3, 4) + ","
      + NumToStr(p.rot.q4, 4) + "]]";
  ENDFUNC

  ! At most 80 characters: an event log line (and a RAPID string) holds no more.
  FUNC string tb_clip(string s)
    IF StrLen(s) > 80 RETURN StrPart(s, 1, 80);
    RETURN s;
  ENDFUNC

  PROC tb_command()
    VAR string what;
    IF tb_n >= TB_MAX_CMDS THEN
      tb_fail "Too many commands", "more than " + NumToStr(TB_MAX_CMDS, 0);
    ENDIF
    tb_n := tb_n + 1;
    tb_what := "command " + NumToStr(tb_n, 0);
    tb_cmd{tb_n} := tb_num();
    tb_op{tb_n} := tb_num();
    what := "cmd_num " + NumToStr(tb_cmd{tb_n}, 0);
    TEST tb_op{tb_n}
    CASE 1:
      tb_what := "MoveAbsJ " + what + " jointtarget";
      tb_jt{tb_n} := tb_jointtarget();
      tb_speed{tb_n} := tb_speeddata("MoveAbsJ " + what);
      tb_zone{tb_n} := tb_zonedata("MoveAbsJ " + what);
    CASE 2:
      tb_target "MoveJ " + what;
    CASE 3:
      tb_target "MoveL " + what;
    CASE 5:
      what := "WaitTime " + what;
      tb_what := what;
      tb_wait{tb_n} := tb_num();
      IF tb_wait{tb_n} < 0 THEN
        tb_fail "Invalid WaitTime", what + ": " + NumToStr(tb_wait{tb_n}, 2) + " s";
      ENDIF
      IF tb_wait{tb_n} > TB_WAIT_MAX THEN
        tb_fail TB_WAIT_OVER, tb_clip(what + ": " + NumToStr(tb_wait{tb_n}, 2)
          + " s > TB_WAIT_MAX " + NumToStr(TB_WAIT_MAX, 2));
      ENDIF
    CASE 4:
      tb_fail "Unsupported command", "MoveC " + what;
    CASE 6:
      tb_fail "Unsupported command", "CirPathMode " + what;
    CASE 7:
      tb_fail "Unsupported command", "SyncMoveOn " + what;
    CASE 8:
      tb_fail "Unsupported command", "SyncMoveOff " + what;
    DEFAULT:
      tb_fail "Invalid motion program command", "unknown opcode " + NumToStr(tb_op{tb_n}, 0)
        + " (" + what + ")";
    ENDTEST
  ENDPROC

  PROC tb_target(string what)
    tb_what := what + " robtarget";
    tb_pt{tb_n} := tb_robtarget();
    IF tb_pt{tb_n}.trans.z < tb_floor_z THEN
      tb_fail "Target below the table", what + ": z " + NumToStr(tb_pt{tb_n}.trans.z, 1)
        + " mm < " + NumToStr(tb_floor_z, 1) + " mm";
    ENDIF
    tb_speed{tb_n} := tb_speeddata(what);
    tb_zone{tb_n} := tb_zonedata(what);
  ENDPROC

  ! --- running it ------------------------------------------------------------------------
  PROC tb_execute()
    ! ConfJ Off: the pushes' targets come from the picture, all over the workspace, and
    ! with the pusher pointing down axis 6's quadrant (cf6), and axis 1's, change across
    ! it: no one confdata a lab could measure holds for every target (the twin's IRB 14000
    ! model: at the pushes' arm angle the left workspace's corners need different cf1,
    ! cf4, cf6). With ConfJ On a MoveJ to a target in another quadrant stops the task
    ! (50080). Off, the controller takes the closest configuration; the arm angle (axis
    ! 7, from the calibration) still fixes the redundancy. MoveL keeps the configuration
    ! it starts in, as a push is a short line. SingArea Wrist: the pusher is round, so
    ! the controller may turn the tool about its own axis to keep the wrist (axes 4 and
    ! 6 in line when axis 5 is near 0, the forearm over a tool pointing down) away from
    ! its singularity instead of stopping a push with 50026 "Close to singularity".
    ! VelSet: the second layer of the TCP speed cap (the module's comment, "What it does"):
    ! every move below runs at most tb_v_tcp_max at its TCP, whatever its speeddata.
    ConfJ \Off;
    ConfL \Off;
    SingArea \Wrist;
    VelSet 100, tb_v_tcp_max;
    FOR i FROM 1 TO tb_n DO
      TEST tb_op{i}
      CASE 1:
        MoveAbsJ tb_jt{i}, tb_speed{i}, tb_zone{i}, tool_pusher;
      CASE 2:
        MoveJ tb_pt{i}, tb_speed{i}, tb_zone{i}, tool_pusher \WObj:=wobj0;
      CASE 3:
        MoveL tb_pt{i}, tb_speed{i}, tb_zone{i}, tool_pusher \WObj:=wobj0;
      CASE 5:
        WaitTime \InPos, tb_wait{i};
      ENDTEST
    ENDFOR
    ! a last fly-by point is not the end: "done" means the arm is there
    WaitRob \InPos;
  ENDPROC
ENDMODULE
